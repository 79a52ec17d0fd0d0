"""The sampling-imbalance study (the paper's Figure 4): error against the number of models K.

For each curve kind (lines, circles, ellipses) one SubspaceNet (F = 1, 2-D points, the `lce` recipe's
architecture and training settings, from scratch) is trained on single-kind problems with K drawn from
2..6 per sample, then tested per K on test problems with exactly K curves: SubspaceNet with the true K
and with automatic K (cluster_auto_k), and sequential RANSAC (studies/ransac_curves.py) with the true K and the
generator's noise level, on the same points. A hypothesise-and-test method needs an all-inlier minimal
sample, whose chance falls with K; the paper's claim is that the learned embedding does not degrade so.

Parts under OUT/parts: one checkpoint per kind (`model__<kind>.pt`, its recipe holds the hash of what
training depends on) and one JSON per (kind, K) with the per-sample rows (keyed by that model's weights,
the test settings and the RANSAC settings), so an interrupted run resumes and a re-run reuses both.

Nothing heavy is imported at import time (registry.py reads `IMBALANCE_BUDGETS` when it is imported);
the helpers it shares with the other studies are common.py's.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mosegpipe.embed.model import ModelConfig, SubspaceNet
    from mosegpipe.studies.common import Study, StudyRequest, StudyResult
    from mosegpipe.studies.ransac_curves import RansacConfig
    from mosegpipe.synth.lce import LCEConfig
    from mosegpipe.training.loop import TrainConfig
    from mosegpipe.types import LabeledClip

log = logging.getLogger(__name__)

KINDS = ("line", "circle", "ellipse")
"""The curve kinds, one trained model each."""

KIND_TITLES = {"line": "lines", "circle": "circles", "ellipse": "ellipses"}

METHODS = ("subspacenet_true_k", "subspacenet_auto_k", "ransac")
METHOD_TITLES = {
    "subspacenet_true_k": "SubspaceNet, true K",
    "subspacenet_auto_k": "SubspaceNet, auto K",
    "ransac": "RANSAC, true K",
}

_VERSION = 1
"""Bumped when the study's computation changes, so that stored parts of the old code are redone."""


@dataclass(frozen=True)
class ImbalanceBudget:
    """What one --budget means for this study (plain numbers; the configs are built from the `lce` recipe).

    Attributes:
        num_train: training samples per kind (generated lazily; K drawn from 2..6 per sample).
        num_test: test samples per kind and K.
        steps: optimiser steps per kind.
        batch_size: samples per step.
        num_blocks: residual blocks (None = the lce recipe's).
        width: channels (None = the lce recipe's).
    """

    num_train: int
    num_test: int
    steps: int
    batch_size: int = 16
    num_blocks: int | None = None
    width: int | None = None

    def describe(self) -> str:
        """One line for the budget note: every number the budget sets."""
        net = (
            "the lce recipe's 30 x 64 network"
            if self.num_blocks is None and self.width is None
            else (f"{self.num_blocks} blocks x {self.width} wide")
        )
        return (
            f"per kind: {self.num_train} training samples (K drawn from 2..6), {self.steps} steps of "
            f"{self.batch_size} samples, {net}; {self.num_test} test samples per K"
        )


IMBALANCE_BUDGETS: dict[str, ImbalanceBudget] = {
    # Measured: 564 s of CPU (user + system) for the whole cpu run, three models and 750 test problems, on
    # one core of the 2-core development machine (61 min wall while other jobs shared it).
    "cpu": ImbalanceBudget(num_train=8000, num_test=50, steps=800),
    # The paper's data sizes; 20 passes over the 8000 training samples (meant for a faster machine).
    "full": ImbalanceBudget(num_train=8000, num_test=200, steps=10000),
}


def _configs(budget: ImbalanceBudget) -> tuple[TrainConfig, ModelConfig]:
    from dataclasses import replace

    from mosegpipe.training.recipes import get_recipe

    recipe = get_recipe("lce")
    train = replace(recipe.train, steps=budget.steps, batch_size=budget.batch_size)
    model = recipe.model
    if budget.num_blocks is not None:
        model = replace(model, num_blocks=budget.num_blocks)
    if budget.width is not None:
        model = replace(model, width=budget.width)
    return train, model


def _ransac_config(noise_sigma: float) -> RansacConfig:
    from mosegpipe.studies.ransac_curves import RansacConfig

    return RansacConfig(noise_sigma=noise_sigma)


def _train_kind(
    req: StudyRequest, study: Study, kind: str, budget: ImbalanceBudget, say: Callable[[str], None]
) -> tuple[SubspaceNet, dict[str, Any]]:
    """The trained model of one kind: the stored part when its hash matches, else trained and stored."""
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.studies.common import part_path, stable_hash
    from mosegpipe.synth.lce import LCEConfig, single_kind_splits
    from mosegpipe.training.loop import recipe_of, train_model

    train_cfg, model_cfg = _configs(budget)
    gen = LCEConfig()
    chash = stable_hash(
        {
            "study": study.name,
            "v": _VERSION,
            "kind": kind,
            "num_train": budget.num_train,
            "train": asdict(train_cfg),
            "model": model_cfg.to_dict(),
            "generator": asdict(gen),
        }
    )
    path = part_path(req, f"model__{kind}", ".pt")
    if path.is_file():
        try:
            stored = SubspaceNet.from_checkpoint(path)
        except Exception as exc:  # a torn or foreign file: train again
            log.warning("%s: not reused (%s)", path, exc)
        else:
            if stored.recipe.get("config_hash") == chash:
                say(f"{kind}: model trained earlier ({path.name})")
                return stored, dict(stored.recipe)
    train = single_kind_splits(kind, num_train=budget.num_train, num_test=0, seed=0, cfg=gen)["train"]

    def draw(rng: np.random.Generator) -> LabeledClip:
        return train[int(rng.integers(len(train)))]

    def on_log(entry: dict[str, float]) -> None:
        if int(entry["step"]) % 200 == 0:
            log.info("%s: step %d, loss %.4f, %.0f s", kind, int(entry["step"]), entry["loss"], entry["seconds"])

    result = train_model(draw, train_cfg, model_cfg=model_cfg, on_log=on_log)
    rec = recipe_of(train_cfg, {f"lce-{kind}": {"weight": 1.0, "samples": budget.num_train}}, result)
    rec.update(name=f"{study.name}/{kind}", config_hash=chash)
    path.parent.mkdir(parents=True, exist_ok=True)
    result.model.save(path, recipe=rec)
    say(f"{kind}: trained {result.steps_done} steps in {result.seconds:.0f} s (final loss {_loss(rec)})")
    return result.model, rec


def _loss(rec: dict[str, Any]) -> str:
    loss = rec.get("final_loss")
    return "n/a" if loss is None else f"{loss:.4f}"


def imbalance_rows(
    model: SubspaceNet, clips: list[LabeledClip], kind: str, k_max: int, noise_sigma: float
) -> list[dict[str, Any]]:
    """Per test problem: SubspaceNet with the true K and with automatic K, sequential RANSAC with the true K.

    Args:
        model: an F = 1 SubspaceNet for 2-D points.
        clips: LabeledClips of `kind` with (N, 2) points.
        kind: "line", "circle" or "ellipse" (what RANSAC fits).
        k_max: largest K of the automatic-K rule.
        noise_sigma: the generator's noise level, given to RANSAC (threshold 2.5 sigma).

    Returns:
        One dict per clip: name, num_points, k_true, k_pred (automatic K), errors "subspacenet_true_k",
        "subspacenet_auto_k", "ransac" (fractions in [0, 1]), "ransac_hypotheses" (minimal samples
        drawn in all) and "ransac_seconds".
    """
    from dataclasses import replace

    from mosegpipe.evaluation.benchmark import evaluate_clips
    from mosegpipe.evaluation.metrics import misclassification_error
    from mosegpipe.group.cluster import ClusterConfig
    from mosegpipe.studies.ransac_curves import sequential_ransac

    base = _ransac_config(noise_sigma)
    scored = evaluate_clips(model, clips, ClusterConfig(k_max=k_max))
    rows = []
    for i, (clip, row) in enumerate(zip(clips, scored, strict=True)):
        t0 = time.perf_counter()
        fit = sequential_ransac(clip.traj, kind, clip.k, replace(base, seed=i))
        seconds = time.perf_counter() - t0
        rows.append(
            {
                "name": clip.name,
                "num_points": clip.num_points,
                "k_true": clip.k,
                "k_pred": int(row["k_pred"]),
                "subspacenet_true_k": float(row["error_true_k"]),
                "subspacenet_auto_k": float(row["error"]),
                "ransac": misclassification_error(fit.labels, clip.labels),
                "ransac_hypotheses": int(sum(fit.num_hypotheses)),
                "ransac_seconds": round(seconds, 4),
            }
        )
    return rows


def summarize_imbalance(parts: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Per kind and K: the mean error of each method (%), the correct-K rate (%) and the sample count.

    Args:
        parts: dicts with "kind", "k" and "rows" (see imbalance_rows).

    Returns:
        {kind: {str(K): {method: mean %, "correct_k": %, "samples": n, "ransac_hypotheses": mean}}}.
    """
    out: dict[str, dict[str, dict[str, float]]] = {}
    for part in parts:
        rows = part["rows"]
        cell: dict[str, float] = {m: round(100.0 * float(np.mean([r[m] for r in rows])), 2) for m in METHODS}
        cell["correct_k"] = round(100.0 * float(np.mean([r["k_pred"] == r["k_true"] for r in rows])), 1)
        cell["samples"] = len(rows)
        cell["ransac_hypotheses"] = round(float(np.mean([r["ransac_hypotheses"] for r in rows])), 1)
        out.setdefault(part["kind"], {})[str(part["k"])] = cell
    return out


def table_text(summary: dict[str, dict[str, dict[str, float]]], notes: list[str]) -> str:
    kinds = list(summary)
    ks = sorted({int(k) for kind in kinds for k in summary[kind]})
    head = ["K"] + [f"{KIND_TITLES.get(kind, kind)}: {METHOD_TITLES[m]}" for kind in kinds for m in METHODS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k in ks:
        cells = [str(k)]
        for kind in kinds:
            cell = summary[kind].get(str(k))
            cells += ["" if cell is None else f"{cell[m]:.2f}" for m in METHODS]
        lines.append("| " + " | ".join(cells) + " |")
    head2 = ["K"] + [f"{KIND_TITLES.get(kind, kind)}: correct K (%)" for kind in kinds]
    lines2 = ["| " + " | ".join(head2) + " |", "|" + "---|" * len(head2)]
    for k in ks:
        cells = [str(k)] + [
            "" if summary[kind].get(str(k)) is None else f"{summary[kind][str(k)]['correct_k']:.1f}" for kind in kinds
        ]
        lines2.append("| " + " | ".join(cells) + " |")
    return "\n".join(
        [
            "# Study: sampling-imbalance (the paper's Figure 4)",
            "",
            *notes,
            "",
            "Mean misclassification error (%) per K:",
            "",
            *lines,
            "",
            "SubspaceNet's automatic K: correct-K rate (%):",
            "",
            *lines2,
            "",
        ]
    )


def plot_summary(summary: dict[str, dict[str, dict[str, float]]]) -> Any:
    from mosegpipe.studies.common import pyplot_module

    plt = pyplot_module()
    kinds = list(summary)
    fig, axes = plt.subplots(1, len(kinds), figsize=(3.2 * len(kinds), 3.2), sharey=True, squeeze=False)
    styles = {"subspacenet_true_k": ("C0", "-"), "subspacenet_auto_k": ("C0", "--"), "ransac": ("C3", "-")}
    for ax, kind in zip(axes[0], kinds, strict=True):
        ks = sorted(int(k) for k in summary[kind])
        for m in METHODS:
            colour, style = styles[m]
            ax.plot(
                ks,
                [summary[kind][str(k)][m] for k in ks],
                style,
                color=colour,
                marker="o",
                ms=3,
                label=METHOD_TITLES[m],
            )
        ax.set_title(KIND_TITLES.get(kind, kind), fontsize=9)
        ax.set_xlabel("number of models K", fontsize=8)
        ax.set_xticks(ks)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("misclassification error (%)", fontsize=8)
    axes[0][0].set_ylim(bottom=0)
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    return fig


def run_sampling_imbalance(study: Study, req: StudyRequest) -> StudyResult:
    """Figure 4: error against the number of models for SubspaceNet and sequential RANSAC (see the module docstring)."""
    from mosegpipe.studies.common import (
        StudyResult,
        check_budget,
        load_part,
        model_id,
        part_path,
        save_part,
        stable_hash,
        write_outputs,
    )
    from mosegpipe.synth.lce import SINGLE_KIND_K, LCEConfig, single_kind_splits

    budget_name = check_budget(req)
    budget = IMBALANCE_BUDGETS[budget_name]
    say = req.progress or (lambda _msg: None)
    gen = LCEConfig()
    ransac_cfg = _ransac_config(gen.noise_sigma)
    parts: list[dict[str, Any]] = []
    training: dict[str, dict[str, Any]] = {}
    computed = 0
    for kind in KINDS:
        model, rec = _train_kind(req, study, kind, budget, say)
        mid = model_id(model)
        training[kind] = {
            "weights": mid,
            "steps_done": rec.get("steps_done"),
            "seconds": rec.get("seconds"),
            "final_loss": rec.get("final_loss"),
        }
        splits = single_kind_splits(kind, num_train=0, num_test=budget.num_test, seed=0, cfg=gen)
        for k in SINGLE_KIND_K:
            chash = stable_hash(
                {
                    "study": study.name,
                    "v": _VERSION,
                    "kind": kind,
                    "k": k,
                    "num_test": budget.num_test,
                    "model": mid,
                    "k_max": req.k_max,
                    "ransac": asdict(ransac_cfg),
                    "generator": asdict(gen),
                }
            )
            path = part_path(req, f"test__{kind}__k{k}", ".json")
            payload = load_part(path, chash)
            if payload is None:
                rows = imbalance_rows(model, list(splits[f"test/k{k}"]), kind, req.k_max, gen.noise_sigma)
                payload = {"kind": kind, "k": k, "rows": rows}
                save_part(path, chash, payload)
                computed += 1
                mean = {m: 100.0 * float(np.mean([r[m] for r in rows])) for m in METHODS}
                say(
                    f"{kind} K={k}: SubspaceNet {mean['subspacenet_true_k']:.2f} % (true K), "
                    f"{mean['subspacenet_auto_k']:.2f} % (auto K); RANSAC {mean['ransac']:.2f} %"
                )
            parts.append(payload)
    log.info("sampling-imbalance: %d test parts computed, %d reused", computed, len(parts) - computed)
    summary = summarize_imbalance(parts)
    notes = _notes(budget_name, budget, gen, ransac_cfg, req.k_max, training)
    table = table_text(summary, notes)
    results = {
        "study": study.name,
        "budget": budget_name,
        "budget_settings": asdict(budget),
        "k_max": req.k_max,
        "ransac": asdict(ransac_cfg),
        "training": training,
        "summary": summary,
        "parts": parts,
    }
    files = write_outputs(req, table, results, plot_summary(summary))
    return StudyResult(table, results, files)


def _notes(
    budget_name: str,
    budget: ImbalanceBudget,
    gen: LCEConfig,
    ransac_cfg: RansacConfig,
    k_max: int,
    training: dict[str, dict[str, Any]],
) -> list[str]:
    """The lines under the study's table: budget, data, RANSAC's settings, training, the error."""
    trained = "; ".join(
        f"{kind}: {t['steps_done']} steps, {t['seconds']} s, final loss {_loss(t)}, weights {t['weights']}"
        for kind, t in training.items()
    )
    notes = [
        f"Budget: {budget_name} ({budget.describe()}).",
        f"Data: K curves of one kind per problem, the LCE generator's parameter ranges, 20-60 points per curve, "
        f"noise sigma {gen.noise_sigma} (synth/lce.py, seed 0). SubspaceNet: F = 1, trained from scratch per "
        f"kind on K = 2..6 mixed; automatic K by cluster.py's default rule, K in 1..{k_max}.",
        f"RANSAC: sequential, uniform minimal samples (2 / 3 / 5 points), given the true K and the noise level: "
        f"inlier threshold {ransac_cfg.threshold_sigmas} sigma = {ransac_cfg.threshold:.3f}, at most "
        f"{ransac_cfg.max_hypotheses} samples per model (adaptive stop at confidence {ransac_cfg.confidence}), "
        f"{ransac_cfg.refits} least-squares refits, then every point to its nearest curve.",
        f"Training: {trained}.",
        "Error: misclassification rate (Hungarian matching), mean over the test samples, in percent.",
    ]
    return notes
