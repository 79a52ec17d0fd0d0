"""Grouping tracks into motions: K-means with automatic K, the rigid check, joint and geometric model
selection, which motion is the world, labels across windows."""
