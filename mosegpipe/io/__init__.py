"""Reading and writing: videos, frame folders and images (read); atomic writers (write); what an input was
(provenance); one command at a time in an output folder (locks)."""
