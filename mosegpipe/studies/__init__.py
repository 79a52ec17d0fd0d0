"""The paper's studies behind `moseg study NAME`: each writes a table, results.json and a plot, resumably.

Modules:
    registry: the `Study` registry (`STUDIES`, `get_study`) and the model-selection and t-SNE studies.
    common: what the studies share (records, resumable parts, budgets, test clips, figures).
    imbalance: the sampling-imbalance study (error against the number of models, Figure 4).
    ransac_curves: sequential RANSAC for K lines, circles or ellipses (that study's baseline).
    lce: learning curves on the synthetic lines / circles / ellipses benchmark.
    training: the training studies (losses, supervision, embedding dimension, network, depth).

The studies score with evaluation/ (metrics, baselines, benchmark runners); nothing in evaluation/ or
in the inference pipeline imports this package. Nothing heavy is imported at import time.
"""

from __future__ import annotations

from mosegpipe.studies.common import Budget, Study, StudyRequest, StudyResult
from mosegpipe.studies.registry import STUDIES, get_study

__all__ = ["STUDIES", "Budget", "Study", "StudyRequest", "StudyResult", "get_study"]
