"""Evaluation: metrics, baselines, label transfer, the protocol registry and the report writer.

Modules:
    metrics: misclassification error, NMI, correct-K rate (pure NumPy).
    baselines: K-means, spectral clustering and sparse subspace clustering on raw trajectories.
    ransac_curves: sequential RANSAC for K lines, circles or ellipses (the sampling-imbalance baseline).
    label_transfer: ground-truth labels for our own tracks and matches.
    benchmark: protocols on labelled trajectory benchmarks (KT3DMoSeg, Hopkins155, AdelaideRMF, LCE).
    e2e: end-to-end protocols (our own tracks or matches against ground truth; mask J / boundary F).
    protocols: the `Protocol` registry behind `moseg eval NAME` (a new protocol is one entry).
    folds: how labelled clips group into leave-one-out folds (sequence_of).
    report: summaries, Markdown tables and the results files.
    study_common: what the studies share (records, resumable parts, budgets, figures).
    studies: the `Study` registry behind `moseg study NAME` (tables, results.json and a plot per study).
    study_imbalance: the sampling-imbalance study (error against the number of models, Figure 4).

Nothing in the inference pipeline imports this package.
"""
