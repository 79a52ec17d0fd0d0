"""What runs the pipeline for a user: Segmenter, the output folders, batches of clips, live sources."""
