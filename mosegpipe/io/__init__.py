"""Reading and writing: videos, frame folders and images (read); atomic writers (write); what an input was (provenance)."""
