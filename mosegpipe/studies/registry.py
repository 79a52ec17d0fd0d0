"""The study registry: every `moseg study NAME` (one study of the paper) is one `Study` record.

A study writes `table.md`, `results.json` and `plot.png` to its output folder, and keeps each finished
part (one clip, one fold) in `OUT/parts/` under a hash of everything the part depends on, so an
interrupted run resumes and a re-run skips what is done. Every study takes a budget: "cpu" (what fits
a small CPU machine) or "full" (the paper's scale); a study whose two budgets are the same says so in
its table. Adding a study is adding one record to `STUDIES`:

    Study("tsne", "...", paper="Figure 3, bottom row", run=run_tsne, needs_data=True,
          budgets={"cpu": "...", "full": "..."})

Like protocols.py, this module imports nothing heavy at import time.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

import numpy as np
import numpy.typing as npt

from mosegpipe.errors import ConfigError, lookup
from mosegpipe.studies.common import (
    DATASET_TITLES,
    PARTS_VERSION,
    Study,
    StudyRequest,
    StudyResult,
    budget_note,
    check_budget,
    load_datasets,
    load_part,
    model_id,
    part_path,
    pyplot_module,
    resolve_data_root,
    save_part,
    stable_hash,
    study_models,
    write_outputs,
)

if TYPE_CHECKING:
    from mosegpipe.types import LabeledClip

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# model-selection (Table 5): every automatic-K rule on the same embeddings, and the baselines' own


# The baselines' own automatic K (see baselines.py): the name shown, the baseline, how it picks K.
_BASELINE_RULES = (
    ("kmeans-raw", "cluster.py's default rule on the z-scored trajectories"),
    ("spectral-raw", "eigengap of the normalised Laplacian"),
    ("ssc", "eigengap of the SSC affinity"),
)


def model_selection_rows(
    clip: LabeledClip, emb: npt.NDArray[np.float32] | None, k_max: int = 8
) -> dict[str, dict[str, float | int]]:
    """Every K rule on one clip: {method: {"k": chosen K, "error": misclassification error}}.

    Args:
        clip: a labelled clip (its trajectories feed the baselines).
        emb: (N, E) SubspaceNet embeddings of the clip (None: baselines only).
        k_max: largest K considered by the embedding rules (the baselines use their own, 8).

    Returns:
        Methods "<rule>" for each automatic-K rule of cluster.py on the embeddings, "true K" (the
        same embeddings with K given, for reference) and "<baseline>" for each baseline's own choice.
    """
    from mosegpipe.evaluation.baselines import BASELINES
    from mosegpipe.evaluation.metrics import misclassification_error
    from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
    from mosegpipe.types import KMethodName

    out: dict[str, dict[str, float | int]] = {}
    if emb is not None:
        for rule in get_args(KMethodName):
            res = cluster_auto_k(emb, ClusterConfig(method=rule, k_max=k_max))
            out[rule] = {"k": int(res.k), "error": misclassification_error(res.labels, clip.labels)}
        fixed = cluster_auto_k(emb, ClusterConfig(k_max=k_max), k=clip.k)
        out["true K"] = {"k": clip.k, "error": misclassification_error(fixed.labels, clip.labels)}
    for name, _ in _BASELINE_RULES:
        labels = BASELINES[name](clip.traj, None)
        out[name] = {"k": int(np.unique(labels).size), "error": misclassification_error(labels, clip.labels)}
    return out


def summarize_model_selection(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Per dataset and method: mean and median error (%), correct-K rate (%) and clips.

    Args:
        rows: one dict per clip with "dataset", "k_true" and "methods" (see model_selection_rows).

    Returns:
        {dataset: {method: {"mean": %, "median": %, "correct_k": %, "clips": n}}}.
    """
    out: dict[str, dict[str, dict[str, float]]] = {}
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        mine = [r for r in rows if r["dataset"] == dataset]
        methods = list(dict.fromkeys(m for r in mine for m in r["methods"]))
        out[dataset] = {}
        for m in methods:
            errs = np.array([r["methods"][m]["error"] for r in mine if m in r["methods"]], dtype=np.float64)
            hits = [r["methods"][m]["k"] == r["k_true"] for r in mine if m in r["methods"]]
            out[dataset][m] = {
                "mean": round(100.0 * float(errs.mean()), 2),
                "median": round(100.0 * float(np.median(errs)), 2),
                "correct_k": round(100.0 * float(np.mean(hits)), 1),
                "clips": len(hits),
            }
    return out


def _model_selection_table(summary: dict[str, dict[str, dict[str, float]]], notes: list[str]) -> str:
    from mosegpipe.group.cluster import ClusterConfig
    from mosegpipe.types import KMethodName

    datasets = list(summary)
    methods = list(dict.fromkeys(m for d in datasets for m in summary[d]))
    applied = {rule: "SubspaceNet embeddings" for rule in get_args(KMethodName)}
    applied["true K"] = "SubspaceNet embeddings, K given (reference)"
    applied.update({name: f"{name}: {how}" for name, how in _BASELINE_RULES})
    applied["kmeans-raw"] += f" ({ClusterConfig().method})"
    head = ["K rule", "applied to"]
    for d in datasets:
        title = DATASET_TITLES.get(d, d)
        head += [f"{title} error mean / median (%)", f"{title} correct K (%)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in methods:
        cells = [m, applied.get(m, "")]
        for d in datasets:
            s = summary[d].get(m)
            cells += ["" if s is None else f"{s['mean']:.2f} / {s['median']:.2f}"]
            cells += ["" if s is None or m == "true K" else f"{s['correct_k']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(["# Study: model-selection (the paper's Table 5)", "", *notes, "", *lines, ""])


def _model_selection_plot(summary: dict[str, dict[str, dict[str, float]]]) -> Any:
    plt = pyplot_module()
    datasets = list(summary)
    methods = [m for m in dict.fromkeys(m for d in datasets for m in summary[d]) if m != "true K"]
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    width = 0.8 / max(1, len(datasets))
    x = np.arange(len(methods))
    for i, d in enumerate(datasets):
        vals = [summary[d].get(m, {}).get("correct_k", 0.0) for m in methods]
        bars = ax.bar(x + (i - (len(datasets) - 1) / 2) * width, vals, width, label=DATASET_TITLES.get(d, d))
        ax.bar_label(bars, fmt="%.0f", fontsize=7)
    ax.set_xticks(x, methods)
    ax.set_ylabel("correct K (%)")
    ax.set_ylim(0, 105)
    ax.set_title("Automatic K: correct-K rate per rule")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def run_model_selection(study: Study, req: StudyRequest) -> StudyResult:
    """Table 5: every automatic-K rule on the same embeddings, beside the baselines' own K choice.

    Per clip (KT3DMoSeg frames 1-5 of the 22 sequences with the 5-frame model, the 19 AdelaideRMF pairs
    with the two-view model) one part file under OUT/parts; the table gives per dataset and rule the
    mean / median error with the chosen K and the correct-K rate.
    """
    from mosegpipe.evaluation.benchmark import embed_clip

    budget = check_budget(req)
    root = resolve_data_root(req, study)
    say = req.progress or (lambda _msg: None)
    model5, model2 = study_models(req)
    models = {"kt3dmoseg": model5, "adelaidermf": model2}
    ids = {d: model_id(m) for d, m in models.items()}
    rows: list[dict[str, Any]] = []
    done = 0
    for dataset, clips in load_datasets(root).items():
        chash = stable_hash({"study": study.name, "v": PARTS_VERSION, "model": ids[dataset], "k_max": req.k_max})
        for clip in clips:
            path = part_path(req, f"{dataset}__{clip.name}", ".json")
            payload = load_part(path, chash)
            if payload is None:
                emb = embed_clip(models[dataset], clip)
                payload = {
                    "dataset": dataset,
                    "name": clip.name,
                    "num_points": clip.num_points,
                    "k_true": clip.k,
                    "methods": model_selection_rows(clip, emb, req.k_max),
                }
                save_part(path, chash, payload)
                say(f"{dataset} {clip.name}: done")
                done += 1
            rows.append(payload)
    log.info("model-selection: %d parts computed, %d reused", done, len(rows) - done)
    summary = summarize_model_selection(rows)
    notes = [
        budget_note(study, budget),
        f"Models: {req.model or 'shipped 5-frame'} (KT3DMoSeg, weights {ids['kt3dmoseg']}), "
        f"{req.pair_model or 'shipped two-view'} (AdelaideRMF, weights {ids['adelaidermf']}); "
        f"K in 1..{req.k_max} for the embedding rules, 1..8 for the baselines.",
        "Error: misclassification rate with the chosen K (Hungarian matching); AdelaideRMF outliers are one group.",
    ]
    table = _model_selection_table(summary, notes)
    results = {
        "study": study.name,
        "budget": budget,
        "models": {"kt3dmoseg": ids["kt3dmoseg"], "adelaidermf": ids["adelaidermf"]},
        "k_max": req.k_max,
        "summary": summary,
        "rows": rows,
    }
    files = write_outputs(req, table, results, _model_selection_plot(summary))
    return StudyResult(table, results, files)


# ---------------------------------------------------------------------------------------------
# tsne (Figure 3, bottom row): raw trajectories and embeddings in 2-D

DEFAULT_TSNE_CLIPS = ("Seq005_Clip01", "Seq038_Clip01", "breadcubechips")
"""Two KT3DMoSeg sequences (three and five motions) and one AdelaideRMF pair (three objects + outliers)."""


def tsne_2d(x: npt.ArrayLike, seed: int = 0) -> npt.NDArray[np.float32]:
    """A 2-D t-SNE (scikit-learn, PCA initialisation, one thread) of (N, D) points.

    Perplexity is min(30, (N - 1) / 3) so that small clips stay valid.

    Returns:
        (N, 2) float32 coordinates (unitless).
    """
    from sklearn.manifold import TSNE

    from mosegpipe.runtime import limited_threads

    arr = np.asarray(x, dtype=np.float64)
    perplexity = float(min(30.0, max(1.0, (arr.shape[0] - 1) / 3.0)))
    with limited_threads(1):
        out = TSNE(n_components=2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(arr)
    return np.asarray(out, dtype=np.float32)


def _find_clips(root: Path, names: Sequence[str]) -> list[tuple[str, LabeledClip]]:
    from mosegpipe.evaluation.folds import sequence_of

    datasets = load_datasets(root)
    found = []
    for name in names:
        hits = [(d, c) for d, clips in datasets.items() for c in clips if name in (c.name, sequence_of(c))]
        if not hits:
            known = ", ".join(sequence_of(c) for clips in datasets.values() for c in clips)
            raise ConfigError(f"--clips {name}: no such KT3DMoSeg sequence or AdelaideRMF pair (choose from {known})")
        found.append(hits[0])
    return found


def _tsne_plot(panels: list[dict[str, Any]]) -> Any:
    plt = pyplot_module()
    fig, axes = plt.subplots(len(panels), 2, figsize=(7.0, 3.2 * len(panels)), squeeze=False)
    for row, panel in enumerate(panels):
        labels = np.asarray(panel["labels"])
        for col, (key, what) in enumerate((("raw", "trajectories (z-scored)"), ("embedding", "SubspaceNet embedding"))):
            ax = axes[row][col]
            xy = np.asarray(panel[key])
            ax.scatter(xy[:, 0], xy[:, 1], c=labels, cmap="tab10", vmin=0, vmax=9, s=5, linewidths=0)
            ax.set_title(f"{panel['name']}: {what}", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("t-SNE, coloured by ground truth", fontsize=9)
    fig.tight_layout()
    return fig


def run_tsne(study: Study, req: StudyRequest) -> StudyResult:
    """Figure 3 (bottom row): t-SNE of the raw trajectories and of the embeddings of chosen clips.

    The raw input is the column-z-scored trajectory matrix (as the baselines see it); the embedding
    is the model's (N, 5) output. Each clip's two 2-D maps are one part under OUT/parts.
    """
    from mosegpipe.evaluation.baselines import zscore_columns
    from mosegpipe.evaluation.benchmark import embed_clip

    budget = check_budget(req)
    root = resolve_data_root(req, study)
    say = req.progress or (lambda _msg: None)
    names = req.clips or DEFAULT_TSNE_CLIPS
    chosen = _find_clips(root, names)
    model5, model2 = study_models(req)
    models = {"kt3dmoseg": model5, "adelaidermf": model2}
    panels = []
    rows = []
    for dataset, clip in chosen:
        mid = model_id(models[dataset])
        chash = stable_hash({"study": study.name, "v": PARTS_VERSION, "model": mid})
        path = part_path(req, f"{dataset}__{clip.name}", ".json")
        payload = load_part(path, chash)
        if payload is None:
            emb = embed_clip(models[dataset], clip)
            payload = {
                "dataset": dataset,
                "name": clip.name,
                "num_points": clip.num_points,
                "k_true": clip.k,
                "labels": clip.labels.tolist(),
                "raw": tsne_2d(zscore_columns(clip.traj)).tolist(),
                "embedding": tsne_2d(emb).tolist(),
            }
            save_part(path, chash, payload)
            say(f"{dataset} {clip.name}: t-SNE done")
        panels.append(payload)
        rows.append({k: payload[k] for k in ("dataset", "name", "num_points", "k_true")} | {"model": mid})
    lines = [
        "# Study: tsne (the paper's Figure 3, bottom row)",
        "",
        budget_note(study, budget),
        "t-SNE (scikit-learn, 2-D, PCA init, seed 0) of the z-scored trajectory matrix and of the embeddings; "
        "colours: ground-truth groups. Picture: plot.png.",
        "",
        "| dataset | clip | points | K (ground truth) | model weights |",
        "|---|---|---|---|---|",
        *(f"| {r['dataset']} | {r['name']} | {r['num_points']} | {r['k_true']} | {r['model']} |" for r in rows),
        "",
    ]
    table = "\n".join(lines)
    results = {"study": study.name, "budget": budget, "clips": rows}
    files = write_outputs(req, table, results, _tsne_plot(panels))
    return StudyResult(table, results, files)


# ---------------------------------------------------------------------------------------------

_NO_TRAINING = "no training: one pass over the test clips"


def _run_sampling_imbalance(study: Study, req: StudyRequest) -> StudyResult:
    from mosegpipe.studies.imbalance import run_sampling_imbalance

    return run_sampling_imbalance(study, req)


def _imbalance_budgets() -> dict[str, str]:
    from mosegpipe.studies.imbalance import IMBALANCE_BUDGETS

    return {name: b.describe() for name, b in IMBALANCE_BUDGETS.items()}


def _run_lce_curve(study: Study, req: StudyRequest) -> StudyResult:
    from mosegpipe.studies.lce import run_lce_curve

    return run_lce_curve(study, req)


_STUDIES: Sequence[Study] = (
    Study(
        "model-selection",
        "every automatic-K rule on the same embeddings (KT3DMoSeg test clips, AdelaideRMF pairs) beside "
        "the baselines' own K choice: error and correct-K rate",
        paper="Table 5",
        run=run_model_selection,
        budgets={"cpu": _NO_TRAINING, "full": _NO_TRAINING},
    ),
    Study(
        "tsne",
        "2-D t-SNE of the raw trajectories and of the embeddings of chosen clips, coloured by ground truth",
        paper="Figure 3, bottom row",
        run=run_tsne,
        budgets={"cpu": _NO_TRAINING, "full": _NO_TRAINING},
    ),
    Study(
        "sampling-imbalance",
        "error against the number of models (K = 2..6 lines, circles or ellipses): SubspaceNet trained per "
        "curve kind against sequential RANSAC on the same synthetic problems",
        paper="Figure 4",
        run=_run_sampling_imbalance,
        needs_data=False,
        budgets=_imbalance_budgets(),
    ),
    Study(
        "lce-curve",
        "learning curves on the synthetic lines/circles/ellipses benchmark: error (auto and true K) and NMI "
        "against samples seen, scored at checkpoints of one training run per configuration (budget or design?)",
        paper="the synthetic LCE experiment (18.04 % error, NMI 0.727)",
        run=_run_lce_curve,
        needs_data=False,
        budgets={
            "cpu": "the recipe 4000 steps of 16 samples (64 k samples seen), two alternatives 2000 steps of 16 each, "
            "and the recipe with 64 samples per step for 2000 steps (128 k samples); 6 checkpoints per run; val: "
            "first 100 of 200, test: all 200; about 55 min of one CPU core",
            "full": "the recipe only, 20 000 steps of 64 samples (1.28 M samples seen; the paper: 2.4 M), 6 "
            "checkpoints, on the GPU when there is one (estimated under 10 min on one GPU); val: first 100, test: "
            "all 200",
        },
    ),
)


def _training_studies() -> tuple[Study, ...]:
    from mosegpipe.studies.training import training_study_records

    return tuple(
        Study(name, desc, paper=paper, run=run, budgets=budgets)
        for name, desc, paper, run, budgets in training_study_records()
    )


STUDIES: dict[str, Study] = {s.name: s for s in (*_STUDIES, *_training_studies())}
"""Every study by name (the order of --help and of error messages)."""


def get_study(name: str) -> Study:
    """The study called `name`.

    Raises:
        ConfigError: no study has that name; the message lists them.
    """
    return lookup(STUDIES, name, "study")
