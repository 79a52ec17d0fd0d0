"""The records of the protocol registry, imported by both sides: the registry (`protocols`) and the
runners it calls (`benchmark`, `e2e`, ...), so that neither imports the other back.

`Protocol` is one `moseg eval NAME`; `EvalRequest` what a run asks of it; `EvalResult` what it produced.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.types import LabeledClip

Variant = Literal["vanilla", "augment"]
"""kt3d-loo: "vanilla" (one frames-1..5 clip per training sequence) or "augment" (every 5-frame window)."""


@dataclass(frozen=True)
class EvalRequest:
    """What one `moseg eval` run asks of a protocol (each protocol uses the settings that apply to it).

    Attributes:
        out_dir: results folder (results.md/csv/json; per-fold files to resume).
        data_root: the benchmark folder (None for protocols that generate their data).
        model: a checkpoint file instead of the shipped weights.
        init: leave-one-out folds start from this checkpoint (None = from scratch).
        frames: trajectory length F (None = the protocol's default_frames).
        variant: kt3d-loo training variant.
        recipe: end-to-end leave-one-out: the recipe each fold trains instead of the protocol's
            fold_recipe (None = the protocol's; it must have the protocol's frame count).
        steps, batch_size, lr, loss: per-fold training overrides (None = the defaults).
        synthetic_weight: LOO: weight of synthetic clips mixed into each fold.
        baselines: baseline names run beside SubspaceNet (benchmark protocols).
        folds: only these held-out names (None = all).
        k_method: automatic-K rule ("silhouette" or "residual").
        k_max: largest K considered by automatic K.
        rigid_check: end-to-end protocols: run the rigid-motion check after automatic K
            (PipelineConfig.rigid; False = automatic K alone, as before the check existed).
        mask_method: end-to-end protocols: the dense-mask method (MaskConfig.method; None = the default).
        method: end-to-end protocols: how tracks become motions (PipelineConfig.method, "subspacenet" or
            "geometric"; None = the default). With "geometric", k_max bounds its K too.
        points: end-to-end protocols: where a clip's points come from (PipelineConfig.tracker, "klt",
            "flow" or "klt+flow"; None = the default).
        preset: end-to-end protocols: a named preset (`pipeline.config.PRESETS`; None = the defaults), applied
            after the options above and before `settings`.
        settings: end-to-end protocols: pipeline settings changed by dotted path ("mask.motion.fb_weight=0.5",
            `PipelineConfig.with_settings`), after the options above.
        device: where protocols that train train their models ("cpu", "cuda", "cuda:N" or "auto"; see
            training.loop.resolve_device).
        progress: called with one line per fold / stage.
    """

    out_dir: Path
    data_root: Path | None = None
    model: Path | None = None
    init: Path | None = None
    frames: int | None = None
    variant: str = "vanilla"
    recipe: str | None = None
    steps: int | None = None
    batch_size: int | None = None
    lr: float | None = None
    loss: str | None = None
    synthetic_weight: float = 0.0
    baselines: tuple[str, ...] = ("kmeans-raw", "spectral-raw", "ssc")
    folds: tuple[str, ...] | None = None
    k_method: str = "silhouette"
    k_max: int = 8
    rigid_check: bool = True
    mask_method: str | None = None
    method: str | None = None
    points: str | None = None
    preset: str | None = None
    settings: tuple[str, ...] = ()
    device: str = "cpu"
    progress: Callable[[str], None] | None = field(default=None, compare=False)


@dataclass(frozen=True)
class EvalResult:
    """What a protocol run produced (also written to out_dir).

    Attributes:
        rows: one dict per test clip.
        summary: means / medians and rates over the rows.
        table: the Markdown table that was printed and written to results.md.
    """

    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    table: str


EndToEnd = Callable[
    ["Path | None", "SubspaceNet | None", "PipelineConfig", "Sequence[str] | None", "Sequence[str] | None"],
    list[dict[str, Any]],
]
"""(data_root, model, cfg, names, baselines) -> one row per clip (see evaluation/e2e.py)."""


@dataclass(frozen=True)
class Protocol:
    """One evaluation protocol.

    Attributes:
        name: what `moseg eval NAME` is called with.
        description: one line for --help and the README.
        default_frames: F when --frames is not given.
        data: the folder under the data root it reads (None: its clips are generated).
        run: (protocol, request) -> EvalResult; writes the results files.
        kind: "benchmark" (the dataset's own trajectories) or "end-to-end" (our own tracks or matches).
        load_clips: benchmark protocols: (data_root, frames) -> the labelled test clips.
        train_source: benchmark protocols that train: variant -> the training source of each fold
            (a name in training.recipes.SOURCES); None = never trains.
        fold_key: how test clips group into leave-one-out folds (None = one fold, trained only when
            no model is given).
        end_to_end: end-to-end protocols: (data_root, model, cfg, names, baselines) -> rows; names
            None = every clip, baselines None = none.
        fold_recipe: end-to-end leave-one-out: the training recipe every fold follows (without the
            held-out sequence / pair in any of its sources).
        fold_names: end-to-end leave-one-out: data_root -> the held-out names, one fold each.
    """

    name: str
    description: str
    default_frames: int
    data: str | None
    run: Callable[[Protocol, EvalRequest], EvalResult]
    kind: Literal["benchmark", "end-to-end"] = "benchmark"
    load_clips: Callable[[Path, int], list[LabeledClip]] | None = None
    train_source: Callable[[str], str] | None = None
    fold_key: Callable[[LabeledClip], str] | None = None
    end_to_end: EndToEnd | None = None
    fold_recipe: str | None = None
    fold_names: Callable[[Path], list[str]] | None = None

    @property
    def is_test_only(self) -> bool:
        """Whether it scores a given model and never trains."""
        return (self.kind == "end-to-end" and self.fold_recipe is None) or (
            self.kind == "benchmark" and self.train_source is None
        )
