"""Evaluation: metrics, baselines, label transfer, the protocol registry and the report writer (the paper's
studies are a package of their own, mosegpipe.studies).

Modules:
    metrics: misclassification error, NMI, correct-K rate; mask J, boundary F and mask matching (NumPy).
    baselines: K-means, spectral clustering and sparse subspace clustering on raw trajectories.
    label_transfer: ground-truth labels for our own tracks and matches.
    benchmark: protocols on labelled trajectory benchmarks (KT3DMoSeg, Hopkins155, AdelaideRMF, LCE).
    e2e: end-to-end protocols (our own tracks or matches against ground truth).
    davis: real-video masks against DAVIS-2016 (J / F per sequence, the flow-homography reference).
    records: the protocol records and row types that the registry and the runners share.
    protocols: the `Protocol` registry behind `moseg eval NAME` (a new protocol is one entry).
    folds: how labelled clips group into leave-one-out folds (sequence_of).
    report: summaries, Markdown tables and the results files.

Nothing in the inference pipeline imports this package.
"""
