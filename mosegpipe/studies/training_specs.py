"""What a training study is (Variant, StudyData, TrainingBudget, TrainingStudy) and the paper's
training studies (LOSSES_STUDY, WEAK_STUDY, DIM_STUDY, NETWORK_STUDY, DEPTH_STUDY: TRAINING_STUDIES), which
mosegpipe.studies.training runs."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mosegpipe.errors import ConfigError

if TYPE_CHECKING:
    from mosegpipe.embed.model import ModelConfig


@dataclass(frozen=True)
class Variant:
    """One training setting of a study: what differs from the dataset's default.

    Attributes:
        label: the row of the table.
        loss: training loss (a name in losses.LOSSES).
        model: ModelConfig fields replaced, e.g. (("embed_dim", 3),).
        label_fraction: share of each training clip's labelled points that keep their label; the
            others stay in the clip (they enter the context normalisation) without a label, so they
            take no part in the loss (weak supervision).
        x: the variant's value on the plot's x axis (None: bars instead of lines).
        series: the plot's line the variant belongs to (e.g. the loss in the network study).
    """

    label: str
    loss: str = "l2"
    model: tuple[tuple[str, Any], ...] = ()
    label_fraction: float = 1.0
    x: float | None = None
    series: str = ""

    def __post_init__(self) -> None:
        if not 0.0 < self.label_fraction <= 1.0:
            raise ConfigError(f"Variant {self.label}: label_fraction={self.label_fraction} must lie in (0, 1]")


@dataclass(frozen=True)
class StudyData:
    """A dataset the training studies run on, with its default training setting.

    Attributes:
        name: "kt3dmoseg", "adelaidermf" or "lce".
        frames: F of the trajectories.
        sources: training sources (recipes.SOURCES names) and their weights.
        model: the default architecture (a variant replaces fields of it).
        folds_by_name: whether folds hold out clips by name (KT3DMoSeg sequences, AdelaideRMF pairs);
            False: one fold, a fixed train / test split (lce).
    """

    name: str
    frames: int
    sources: tuple[tuple[str, float], ...]
    model: ModelConfig
    folds_by_name: bool = True


@dataclass(frozen=True)
class TrainingBudget:
    """What a budget means for a training study.

    Attributes:
        steps: optimiser steps per model (batches of 8 clips).
        folds: "two" (even / odd clips held out in turn) or "loo" (leave one out).
        trials: repetitions with other seeds (training seed and, with label_fraction < 1, which
            points keep their labels).
        lce_test: test samples of the lce split scored.
    """

    steps: int
    folds: str = "two"
    trials: int = 1
    lce_test: int = 200

    def describe(self) -> str:
        folds = (
            "two folds (even- / odd-index sequences and pairs held out in turn)"
            if self.folds == "two"
            else "leave one out (22 KT3DMoSeg / 19 AdelaideRMF folds)"
        )
        trials = f", {self.trials} trials" if self.trials > 1 else ""
        return (
            f"{folds}, {self.steps} steps of 8 clips per model from scratch{trials}; lce: {self.lce_test} test samples"
        )


@dataclass(frozen=True)
class TrainingStudy:
    """What one training study runs.

    Attributes:
        title: the table's heading.
        variants: the settings compared, in table order.
        datasets: names in DATASETS.
        budgets: "cpu" / "full" -> TrainingBudget.
        notes: extra lines under the heading.
    """

    title: str
    variants: tuple[Variant, ...]
    datasets: tuple[str, ...]
    budgets: dict[str, TrainingBudget]
    notes: tuple[str, ...] = ()
    x_label: str = ""


# ---------------------------------------------------------------------------------------------
# The studies


_CPU = TrainingBudget(steps=600, lce_test=50)
_FULL = TrainingBudget(steps=3000, folds="loo")

LOSSES_STUDY = TrainingStudy(
    "losses (the paper's Table 2)",
    tuple(
        Variant(label, loss=name)
        for label, name in (
            ("L2 regression", "l2"),
            ("cross-entropy", "ce"),
            ("MaxInterMinIntra", "mimi"),
            ("MaxInterMinIntra, worst point", "mimi-point"),
            ("MaxInterMinIntra, mean scatter", "mimi-mean"),
            ("semi-hard triplet", "triplet"),
            ("lifted structured", "lifted"),
            ("facility location", "facility"),
        )
    ),
    ("kt3dmoseg", "adelaidermf"),
    {"cpu": _CPU, "full": _FULL},
    notes=("The same network (the dataset's default architecture) trained with each loss.",),
)

WEAK_STUDY = TrainingStudy(
    "weak supervision (the paper's Figure 6, right)",
    tuple(Variant(f"{pct} % labelled", label_fraction=pct / 100, x=pct) for pct in (20, 40, 60, 80, 100)),
    ("kt3dmoseg", "adelaidermf"),
    {"cpu": dataclasses.replace(_CPU, trials=2), "full": dataclasses.replace(_FULL, trials=5)},
    notes=(
        "Each training clip keeps the labels of a random share of its labelled points (fixed per clip and "
        "trial); the other points stay in the clip as unlabelled context. Synthetic pairs stay fully labelled.",
    ),
    x_label="labelled points (%)",
)

DIM_STUDY = TrainingStudy(
    "embedding dimension (the paper's Figure 6, middle)",
    tuple(Variant(f"dimension {d}", model=(("embed_dim", d),), x=d) for d in (3, 4, 5, 6, 7)),
    ("kt3dmoseg", "adelaidermf", "lce"),
    {"cpu": _CPU, "full": _FULL},
    x_label="embedding dimension",
)

NETWORK_STUDY = TrainingStudy(
    "networks (the paper's Figure 6, left)",
    tuple(
        Variant(f"{net} / {loss_label}", loss=loss, model=(("arch", arch),))
        for loss, loss_label in (("l2", "L2"), ("mimi", "MIMI"))
        for arch, net in (
            ("subspacenet", "SubspaceNet"),
            ("pointnet", "PointNet-style"),
            ("corresnet", "CorresNet-style"),
        )
    ),
    ("kt3dmoseg", "adelaidermf"),
    {"cpu": _CPU, "full": _FULL},
    notes=(
        "PointNet-style: a shared per-point MLP, a max-pooled global feature concatenated to every point, "
        "no context normalisation. CorresNet-style: context normalisation and batch norm in every layer, "
        "no residual shortcut. Same width, number of blocks and embedding as SubspaceNet.",
    ),
)

DEPTH_STUDY = TrainingStudy(
    "depth and the L2-normalisation layer (the paper's supplementary material)",
    (
        *(
            Variant(f"{b} blocks", model=(("num_blocks", b),), x=b, series="with L2 normalisation")
            for b in (20, 40, 60, 80)
        ),
        *(
            Variant(
                f"{b} blocks, no L2 norm", model=(("num_blocks", b), ("l2_normalize", False)), x=b, series="without"
            )
            for b in (20, 40)
        ),
    ),
    ("kt3dmoseg", "adelaidermf"),
    # A deep model costs steps x blocks: the cpu budget halves the steps (deep models may be under-trained).
    {"cpu": dataclasses.replace(_CPU, steps=300), "full": _FULL},
    x_label="residual blocks",
)


TRAINING_STUDIES: dict[str, tuple[str, str, TrainingStudy]] = {
    "losses": ("Table 2", "every loss with the same network, KT3DMoSeg and AdelaideRMF held-out clips", LOSSES_STUDY),
    "weak-supervision": (
        "Figure 6, right",
        "20-100 % of each training clip's points labelled, mean ± std over trials",
        WEAK_STUDY,
    ),
    "embedding-dim": (
        "Figure 6, middle",
        "embedding dimension 3-7 on KT3DMoSeg, AdelaideRMF and the synthetic curves",
        DIM_STUDY,
    ),
    "networks": (
        "Figure 6, left",
        "SubspaceNet against PointNet- and CorresNet-style networks, L2 and MaxInterMinIntra losses",
        NETWORK_STUDY,
    ),
    "depth": (
        "supplementary material",
        "20-80 residual blocks, with and without the L2-normalisation layer",
        DEPTH_STUDY,
    ),
}
"""name -> (paper reference, one-line description, the study); registry.py registers them."""
