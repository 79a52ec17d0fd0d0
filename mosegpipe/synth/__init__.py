"""Every data generator: synthetic trajectories, rendered video with exact masks, LCE curves.

Modules:
    camera: the shared camera model (poses, rotations, the named camera motions).
    trajectories: synthetic multi-body point trajectories with ground-truth labels (training clips).
    render: rendered video frames of textured moving objects with per-pixel ground-truth masks.
    lce: the lines / circles / ellipses curve dataset of the SubspaceNet paper, and single-kind problems
        (K lines, circles or ellipses) for the sampling-imbalance study.
    composite: real-texture composites, objects cut out of DAVIS clips with their masks and moved over other
        clips, exact per-object masks (the multi-object development and validation set of issue 41).
    seeded: the base of lazily generated datasets (item i is a pure function of the seed and i).

Nothing in the inference pipeline imports this package.
"""
