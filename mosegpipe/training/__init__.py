"""Training: losses, the training loop, recipes (named, reproducible settings) and training sources.

Modules:
    losses: affinity losses on (B, N, E) embeddings (l2, ce, mimi).
    loop: `TrainConfig`, samplers and `train_model`, the one training loop.
    recipes: `Recipe` records and presets (a preset rebuilds a shipped checkpoint), the source registry.

Nothing in the inference pipeline imports this package.
"""
