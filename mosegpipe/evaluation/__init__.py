"""Evaluation: metrics, baselines, label transfer, the protocol registry and the report writer.

Modules:
    metrics: misclassification error, NMI, correct-K rate, mask J and boundary F (pure NumPy).
    baselines: K-means, spectral clustering and sparse subspace clustering on raw trajectories.
    benchmark: protocols on labelled trajectory benchmarks (KT3DMoSeg, Hopkins155, AdelaideRMF, LCE).
    e2e: end-to-end protocols (our own tracks or matches against ground truth; rendered clips).

Nothing in the inference pipeline imports this package.
"""
