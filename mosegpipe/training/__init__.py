"""Training: losses, the training loop, recipes (named, reproducible settings) and training sources.

Modules:
    losses: affinity losses on (B, N, E) embeddings (l2, ce, mimi).
    loop: `TrainConfig`, samplers and `train_model`, the training loop.
    recipes: `Recipe` records (a preset names its init and rebuilds a shipped checkpoint) and the
        `Source` registry of training data (a new source is one entry).
    run: the one training entry point (`train_sources`, `train_recipe`) for `moseg train` and every
        leave-one-out fold.
    own_tracks, augment: training clips made by our own front end, and their point-set augmentation.

Nothing in the inference pipeline imports this package.
"""
