"""Training studies of the paper: one model per (variant, dataset, fold, trial), scored on held-out clips.

The losses (Table 2), weak supervision (Figure 6 right), embedding dimension (Figure 6 middle), network
(Figure 6 left) and depth / L2-normalisation (supplementary) studies all ask the same question of
different training settings: train with setting X, score the clips that training never saw. This
module does that once; each study is a list of `Variant`s (what differs from the dataset's default
setting) and the datasets it runs on.

Every model trains from scratch (an architecture study cannot start from a shared checkpoint) with
the settings of `DATASETS` and the budget's steps:

- "cpu": two folds (the even-index and the odd-index sequences / pairs held out in turn, so every
  test clip is scored once by a model that never saw it), few steps;
- "full": leave one out (22 KT3DMoSeg / 19 AdelaideRMF folds), the paper-like length.

The synthetic curves (lce) have their own train / test split: one fold. Each trained-and-scored
model is one part under OUT/parts, keyed by a hash of everything it depends on, so a run resumes and
a re-run skips it. Like registry.py, this module imports nothing heavy at import time.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mosegpipe.errors import ConfigError
from mosegpipe.studies.training_specs import (
    DEPTH_STUDY,
    DIM_STUDY,
    LOSSES_STUDY,
    NETWORK_STUDY,
    TRAINING_STUDIES,
    WEAK_STUDY,
    StudyData,
    TrainingBudget,
    TrainingStudy,
    Variant,
)

if TYPE_CHECKING:
    from mosegpipe.studies.common import Budget, Study, StudyRequest, StudyResult
    from mosegpipe.training.loop import Sampler
    from mosegpipe.types import LabeledClip

log = logging.getLogger("mosegpipe.studies.training")

__all__ = [
    "DEPTH_STUDY",
    "DIM_STUDY",
    "LOSSES_STUDY",
    "NETWORK_STUDY",
    "TRAINING_STUDIES",
    "WEAK_STUDY",
    "StudyData",
    "TrainingBudget",
    "TrainingStudy",
    "Variant",
    "fold_key",
    "make_folds",
    "run_training_study",
    "scored_clips",
    "study_sampler",
    "summarize_variants",
    "train_and_score",
    "training_study_records",
    "weak_labels",
]


def load_datasets() -> dict[str, StudyData]:
    from mosegpipe.embed.model import ModelConfig

    return {
        # The shipped 5-frame architecture (recipes.py); KT3DMoSeg windows of the training sequences.
        "kt3dmoseg": StudyData(
            "kt3dmoseg", 5, (("kt3d", 1.0),), ModelConfig(in_dim=10, num_blocks=12, input_norm="motion")
        ),
        # The AdelaideRMF pairs of the training folds mixed with synthetic pairs (from scratch, two folds,
        # 600 steps: 7.4 % mean error, against 5.3 % for the benchmark protocol's fine-tuned folds).
        "adelaidermf": StudyData(
            "adelaidermf", 2, (("adelaide", 1.0), ("synthetic-pair", 0.5)), ModelConfig(in_dim=4, num_blocks=12)
        ),
        "lce": StudyData("lce", 1, (("lce", 1.0),), ModelConfig(in_dim=2, num_blocks=30), folds_by_name=False),
    }


def scored_clips(data: StudyData, root: Path | None, budget: TrainingBudget) -> list[LabeledClip]:
    """The clips a dataset's models are scored on (KT3DMoSeg frames 1-5, every AdelaideRMF pair, lce test)."""
    if data.name == "kt3dmoseg":
        from mosegpipe.data.kt3dmoseg import kt3d_test_clips

        return kt3d_test_clips(_need_root(root), frames=data.frames)
    if data.name == "adelaidermf":
        from mosegpipe.data.adelaidermf import load_adelaide

        return load_adelaide(_need_root(root))
    from mosegpipe.synth.lce import lce_splits

    return list(lce_splits()["test"])[: budget.lce_test]


def _need_root(root: Path | None) -> Path:
    if root is None:
        raise ConfigError("this study needs the benchmark data (--data-root or MOSEG_DATA)")
    return root


def fold_key(clip: LabeledClip) -> str:
    """The name a fold holds out: the KT3DMoSeg sequence, or the AdelaideRMF pair's name."""
    from mosegpipe.evaluation.folds import sequence_of

    return sequence_of(clip)


def make_folds(clips: Sequence[LabeledClip], data: StudyData, budget: TrainingBudget) -> list[tuple[str, list[str]]]:
    """(fold name, held-out clip names) per fold; the names are what training sources exclude."""
    names = list(dict.fromkeys(fold_key(c) for c in clips))
    if not data.folds_by_name:
        return [("split", [])]
    if budget.folds == "loo":
        return [(n, [n]) for n in names]
    return [("even", names[0::2]), ("odd", names[1::2])]


def weak_labels(clip: LabeledClip, fraction: float, seed: int) -> LabeledClip:
    """`clip` with all but `fraction` of its labelled points unlabelled (-1), chosen per clip and seed.

    The choice depends on the clip's name and the seed only, so every draw of a clip during training
    sees the same labelled points (as a weakly labelled dataset would). At least one point stays
    labelled when the clip has any.
    """
    import zlib

    if fraction >= 1.0:
        return clip
    labelled = np.flatnonzero(clip.labels >= 0)
    keep = max(1, round(fraction * labelled.size)) if labelled.size else 0
    rng = np.random.default_rng([seed, zlib.crc32(clip.name.encode())])
    kept = rng.choice(labelled, size=keep, replace=False)
    labels = np.full_like(clip.labels, -1)
    labels[kept] = clip.labels[kept]
    return dataclasses.replace(clip, labels=labels)


def study_sampler(
    data: StudyData, root: Path | None, exclude: Sequence[str], label_fraction: float, seed: int
) -> tuple[Sampler, dict[str, Any]]:
    """The training sampler of one fold: the dataset's sources without the held-out names.

    Read sources (benchmark clips) are weakly labelled by `label_fraction`; generated sources
    (synthetic pairs) keep their labels (they are not part of the dataset being studied).
    """
    from mosegpipe.training.loop import clip_sampler, mixture_sampler
    from mosegpipe.training.recipes import get_source, source_clips

    parts: list[tuple[float, Sampler]] = []
    described: dict[str, Any] = {}
    for name, weight in data.sources:
        src = get_source(name)
        if src.generate is not None:
            parts.append((weight, src.generate(data.frames)))
            described[name] = {"weight": weight, "generated": True}
            continue
        clips = [weak_labels(c, label_fraction, seed) for c in source_clips(name, root, data.frames, exclude)]
        if not clips:
            raise ConfigError(f"source {name!r} gave no clips without {sorted(exclude)}")
        parts.append((weight, clip_sampler(clips)))
        described[name] = {"weight": weight, "num_clips": len(clips), "label_fraction": label_fraction}
    return mixture_sampler(parts), described


def train_and_score(
    data: StudyData,
    variant: Variant,
    steps: int,
    root: Path | None,
    held_out: Sequence[str],
    test: Sequence[LabeledClip],
    seed: int = 0,
    device: str = "cpu",
    time_budget_s: float | None = None,
) -> dict[str, Any]:
    """Trains one model of a variant from scratch and scores it on the held-out clips.

    Args:
        device: where the model trains (a checked name, see training.loop.resolve_device).
        time_budget_s: stop training after this many seconds (None: all steps); "steps" says how many ran.

    Returns:
        {"rows": one dict per test clip (name, k_true, k_pred, error, error_true_k, nmi),
         "train_seconds", "steps", "sources"}.
    """
    from mosegpipe.evaluation.benchmark import evaluate_clips
    from mosegpipe.training.loop import TrainConfig, train_model

    model_cfg = dataclasses.replace(data.model, **dict(variant.model))
    cfg = TrainConfig(
        frames=data.frames,
        loss=variant.loss,
        steps=steps,
        batch_size=8,
        lr=1e-3,
        seed=seed,
        time_budget_s=time_budget_s,
    )
    if data.name == "lce":
        cfg = dataclasses.replace(cfg, reverse=False)  # one frame: nothing to reverse
    sampler, described = study_sampler(data, root, held_out, variant.label_fraction, seed)
    result = train_model(sampler, cfg, model_cfg=model_cfg, device=device)
    rows = evaluate_clips(result.model, test)
    keys = ("name", "k_true", "k_pred", "error", "error_true_k", "nmi")
    return {
        "rows": [{k: r[k] for k in keys} for r in rows],
        "train_seconds": round(result.seconds, 1),
        "steps": result.steps_done,
        "sources": described,
    }


def summarize_variants(parts: Sequence[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Per dataset and variant: error means over the clips, then mean and std over the trials.

    Args:
        parts: one dict per trained model: "dataset", "variant", "trial", "rows".

    Returns:
        {dataset: {variant: {"mean", "std" (auto K, over trials), "true_k", "correct_k", "nmi"
        (percent, NMI 0-1), "clips", "trials", "train_seconds" (mean per model)}}}.
    """
    out: dict[str, dict[str, dict[str, float]]] = {}
    for dataset in dict.fromkeys(p["dataset"] for p in parts):
        out[dataset] = {}
        mine = [p for p in parts if p["dataset"] == dataset]
        for variant in dict.fromkeys(p["variant"] for p in mine):
            ours = [p for p in mine if p["variant"] == variant]
            trials = sorted({p["trial"] for p in ours})
            per_trial = []
            for t in trials:
                rows = [r for p in ours if p["trial"] == t for r in p["rows"]]
                per_trial.append(
                    (
                        np.mean([r["error"] for r in rows]),
                        np.mean([r["error_true_k"] for r in rows]),
                        np.mean([r["k_pred"] == r["k_true"] for r in rows]),
                        np.mean([r["nmi"] for r in rows]),
                        len(rows),
                    )
                )
            arr = np.array(per_trial, dtype=np.float64)
            out[dataset][variant] = {
                "mean": round(100.0 * float(arr[:, 0].mean()), 2),
                "std": round(100.0 * float(arr[:, 0].std()), 2),
                "true_k": round(100.0 * float(arr[:, 1].mean()), 2),
                "correct_k": round(100.0 * float(arr[:, 2].mean()), 1),
                "nmi": round(float(arr[:, 3].mean()), 3),
                "clips": int(arr[0, 4]),
                "trials": len(trials),
                "train_seconds": round(float(np.mean([p["train_seconds"] for p in ours])), 1),
            }
    return out


def run_training_study(spec: TrainingStudy, study: Study, req: StudyRequest) -> StudyResult:
    """Trains and scores every (variant, dataset, fold, trial) of `spec`, then writes the table and plot."""
    from mosegpipe.runtime import limited_threads
    from mosegpipe.studies import common as st
    from mosegpipe.training.loop import resolve_device

    budget_name: Budget = st.check_budget(req)
    device = resolve_device(req.device or "cpu")
    budget = spec.budgets[budget_name]
    say = req.progress or (lambda _msg: None)
    datasets = load_datasets()
    parts: list[dict[str, Any]] = []
    computed = 0
    t_start = time.perf_counter()
    prepared = {}
    for dname in spec.datasets:
        clips = scored_clips(datasets[dname], req.data_root, budget)
        prepared[dname] = (clips, make_folds(clips, datasets[dname], budget))
    # Variant-major: the first rows of the table are complete on every dataset first (an interrupted
    # run resumes from the parts either way).
    for variant in spec.variants:
        for dname in spec.datasets:
            data = datasets[dname]
            clips, folds = prepared[dname]
            for trial in range(budget.trials):
                for fold, held_out in folds:
                    test = [c for c in clips if not data.folds_by_name or fold_key(c) in held_out]
                    key = f"{dname}__{_slug(variant.label)}__{fold}__t{trial}"
                    chash = _part_hash(study, data, variant, budget, held_out, test, trial)
                    path = st.part_path(req, key, ".json")
                    payload = st.load_part(path, chash)
                    if payload is None:
                        with limited_threads(1):
                            payload = train_and_score(
                                data, variant, budget.steps, req.data_root, held_out, test, seed=trial, device=device
                            )
                        payload |= {"dataset": dname, "variant": variant.label, "fold": fold, "trial": trial}
                        st.save_part(path, chash, payload)
                        computed += 1
                        err = 100.0 * float(np.mean([r["error"] for r in payload["rows"]]))
                        say(f"{key}: trained in {payload['train_seconds']:.0f} s, error {err:.2f} %")
                    parts.append(payload)
    log.info("%s: %d models trained, %d reused", study.name, computed, len(parts) - computed)
    summary = summarize_variants(parts)
    notes = [
        st.budget_note(study, budget_name),
        *spec.notes,
        "Error: misclassification rate (Hungarian matching) with the automatic K (silhouette, K <= 8), mean "
        "over the test clips (± std over trials); true K: the same embeddings with K given. AdelaideRMF "
        "outliers count as one group.",
        f"Wall time of this run: {time.perf_counter() - t_start:.0f} s ({computed} models trained, "
        f"{len(parts) - computed} reused).",
    ]
    table = table_text(spec, summary, notes)
    results = {
        "study": study.name,
        "budget": budget_name,
        "settings": dataclasses.asdict(budget),
        "variants": [dataclasses.asdict(v) for v in spec.variants],
        "summary": summary,
        "parts": parts,
    }
    files = st.write_outputs(req, table, results, plot_summary(spec, summary))
    return st.StudyResult(table, results, files)


def _part_hash(
    study: Study,
    data: StudyData,
    variant: Variant,
    budget: TrainingBudget,
    held_out: list[str],
    test: Sequence[LabeledClip],
    trial: int,
) -> str:
    """The hash a trained-and-scored part is stored under: everything the model and its scores depend on."""
    from mosegpipe.studies import common as st
    from mosegpipe.training.losses import LOSS_REVISIONS

    return st.stable_hash(
        {
            "study": study.name,
            "v": st.PARTS_VERSION,
            "data": dataclasses.asdict(data),
            "variant": dataclasses.asdict(variant),
            "steps": budget.steps,
            "held_out": held_out,
            "test": [c.name for c in test],
            "trial": trial,
            # A loss whose definition changed gets new parts (mimi: the paper's sum-scatter).
            **({"loss_revision": LOSS_REVISIONS[variant.loss]} if variant.loss in LOSS_REVISIONS else {}),
        }
    )


def _slug(label: str) -> str:
    """A file-name-safe part key: "20 % labelled" -> "20-labelled"."""
    return "-".join("".join(ch if ch.isalnum() else " " for ch in label.lower()).split())


def table_text(spec: TrainingStudy, summary: dict[str, dict[str, dict[str, float]]], notes: list[str]) -> str:
    from mosegpipe.studies.common import DATASET_TITLES

    titles = {**DATASET_TITLES, "lce": "lines/circles/ellipses"}
    head = ["variant"]
    for d in summary:
        head += [f"{titles.get(d, d)} error (%)", "true K (%)", "correct K (%)", "NMI"]
    head.append("training per model (s)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for v in spec.variants:
        cells = [v.label]
        seconds = []
        for d in summary:
            s = summary[d].get(v.label)
            if s is None:
                cells += ["", "", "", ""]
                continue
            spread = f" ± {s['std']:.2f}" if s["trials"] > 1 else ""
            cells += [f"{s['mean']:.2f}{spread}", f"{s['true_k']:.2f}", f"{s['correct_k']:.1f}", f"{s['nmi']:.3f}"]
            seconds.append(s["train_seconds"])
        cells.append(f"{np.mean(seconds):.0f}" if seconds else "")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join([f"# Study: {spec.title}", "", *notes, "", *lines, ""])


def plot_summary(spec: TrainingStudy, summary: dict[str, dict[str, dict[str, float]]]) -> Any:
    from mosegpipe.studies.common import DATASET_TITLES, pyplot_module

    plt = pyplot_module()
    datasets = list(summary)
    fig, axes = plt.subplots(1, len(datasets), figsize=(3.4 * len(datasets) + 0.6, 3.2), squeeze=False)
    numeric = all(v.x is not None for v in spec.variants)
    for ax, d in zip(axes[0], datasets, strict=True):
        if numeric:
            for series in dict.fromkeys(v.series for v in spec.variants):
                vs = [v for v in spec.variants if v.series == series and v.label in summary[d]]
                xs = [float(v.x) for v in vs if v.x is not None]
                ys = [summary[d][v.label]["mean"] for v in vs]
                es = [summary[d][v.label]["std"] for v in vs]
                ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=series or None)
            ax.set_xlabel(spec.x_label)
            if any(v.series for v in spec.variants):
                ax.legend(fontsize=7)
        else:
            vs = [v for v in spec.variants if v.label in summary[d]]
            bars = ax.bar(range(len(vs)), [summary[d][v.label]["mean"] for v in vs])
            ax.bar_label(bars, fmt="%.1f", fontsize=7)
            ax.set_xticks(range(len(vs)), [v.label for v in vs], rotation=30, ha="right", fontsize=7)
        ax.set_title({**DATASET_TITLES, "lce": "lines/circles/ellipses"}.get(d, d), fontsize=9)
        ax.set_ylabel("error, automatic K (%)")
        ax.set_ylim(bottom=0)
    fig.suptitle(spec.title, fontsize=9)
    fig.tight_layout()
    return fig


def _runner(spec: TrainingStudy) -> Callable[[Study, StudyRequest], StudyResult]:
    def run(study: Study, req: StudyRequest) -> StudyResult:
        return run_training_study(spec, study, req)

    return run


def training_study_records() -> list[
    tuple[str, str, str, Callable[[Study, StudyRequest], StudyResult], dict[str, str]]
]:
    """(name, description, paper, run, budgets) for every training study, for the study registry."""
    return [
        (name, desc, paper, _runner(spec), {b: tb.describe() for b, tb in spec.budgets.items()})
        for name, (paper, desc, spec) in TRAINING_STUDIES.items()
    ]
