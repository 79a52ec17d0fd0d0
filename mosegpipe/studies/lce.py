"""lce-curve: learning curves on the paper's synthetic lines / circles / ellipses benchmark.

Is the gap to the paper's LCE result (18.04 % error, NMI 0.727) a matter of training budget or of
design? Each configuration in `CURVE_CONFIGS` is trained in ONE run; at log-spaced checkpoints
(every doubling of the steps, ending at the budget) the model is scored on fixed subsets of the LCE
val and test splits: error with automatic K and with the true K (4), NMI and correct-K rate. A curve
still falling over its last doubling says "budget"; a flat one says "design" (at that budget).

The learning rate is constant after the warm-up (TrainConfig.lr_min_ratio = 1) so that every
checkpoint is a model of the same process and the end of the curve is not flattened by an annealed
learning rate; the `lce` recipe itself decays it (cosine), so its numbers at equal steps differ.

Resumable: each checkpoint's scores are a part under OUT/parts keyed by a hash of the settings, and
the training state (weights, optimizer, data stream) at the latest checkpoint is kept beside them, so
an interrupted run continues from its last checkpoint instead of from scratch. The final weights of
every configuration are written to OUT/models/NAME.pt.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mosegpipe.embed.model import ModelConfig
from mosegpipe.errors import ConfigError
from mosegpipe.studies.common import (
    PARTS_VERSION,
    Study,
    StudyRequest,
    StudyResult,
    budget_note,
    check_budget,
    load_part,
    part_path,
    pyplot_module,
    save_part,
    stable_hash,
    write_outputs,
)
from mosegpipe.training.loop import TrainConfig

if TYPE_CHECKING:
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.training.loop import Sampler, TrainState
    from mosegpipe.types import LabeledClip

log = logging.getLogger(__name__)

PAPER_ERROR = 0.1804
PAPER_NMI = 0.727
PAPER_SAMPLES = 300 * 8000
"""The paper's training: 300 epochs over the 8000 training samples, one sample per step (2.4 M)."""
FULL_STEPS = 20_000
FULL_BATCH = 64
"""--budget full: the recipe only, 20 000 steps of 64 samples (1.28 M samples seen, about half the paper's
2.4 M). Meant for one GPU, where a step of this 30 x 64 network is bound by kernel launches, not by the batch
(estimate: about 20 ms per step, so 400 s of training, plus about 90 s of scoring 6 checkpoints x 300 clips on
the CPU at ~50 ms per clip): under 10 minutes. Not run here (no GPU); the first run reports its own wall time."""


@dataclass(frozen=True)
class CurveConfig:
    """One configuration of the study.

    Attributes:
        name: short name (table rows, part files, models/NAME.pt).
        why: what it tests, for the table.
        model: architecture.
        train: training settings except the number of steps, which the budget sets.
        cpu_steps: steps under --budget cpu (--budget full: the first configuration only, FULL_STEPS of FULL_BATCH).
    """

    name: str
    why: str
    model: ModelConfig
    train: TrainConfig
    cpu_steps: int

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "model": self.model.to_dict(), "train": asdict(self.train)}


def run_training(**overrides: Any) -> TrainConfig:
    # The lce recipe's settings (recipes.py), with a constant learning rate after the warm-up.
    base = TrainConfig(frames=1, batch_size=16, lr=1e-3, flip=True, reverse=False, lr_min_ratio=1.0)
    return TrainConfig(**{**asdict(base), **overrides})


_LCE_MODEL = ModelConfig(in_dim=2, width=64, num_blocks=30, embed_dim=5)

# Probe (docs/RESULTS.md, "lce-curve"): 500 steps of 16 at a constant learning rate, scored on the first
# 60 val samples, error with the true K: recipe 42.19 %, "channel" input norm 42.53 %, lr 3e-3 42.84 %,
# ce loss 43.07 %, 8 x 128 at lr 3e-3 43.70 %, 8 x 128 43.80 %; every run's training loss flat from step
# 300. The two best alternatives by that rule are compared here. The recipe's curve runs twice as long:
# it is the one that answers "budget or design".
CURVE_CONFIGS: tuple[CurveConfig, ...] = (
    CurveConfig(
        "recipe",
        "the lce recipe: 30 blocks x 64, shared input norm, L2 loss, lr 1e-3",
        _LCE_MODEL,
        run_training(),
        cpu_steps=4000,
    ),
    CurveConfig(
        "channel-norm",
        "the recipe with x and y z-scored separately at the input (context normalisation of the input)",
        ModelConfig(in_dim=2, width=64, num_blocks=30, embed_dim=5, input_norm="channel"),
        run_training(),
        cpu_steps=2000,
    ),
    CurveConfig(
        "lr-3e-3",
        "the recipe with a 3x larger learning rate",
        _LCE_MODEL,
        run_training(lr=3e-3),
        cpu_steps=2000,
    ),
    # Does a step of 64 samples learn as much as four steps of 16 (the samples seen are what counts), or
    # only as much as one (the updates are)? The full budget's batch of 64 on a GPU assumes the former.
    CurveConfig(
        "batch-64",
        "the recipe with 64 samples per step: learning per sample seen, or per update?",
        _LCE_MODEL,
        run_training(batch_size=64),
        cpu_steps=2000,
    ),
)
"""The configurations compared, the first being the current `lce` recipe (chosen by the probe above)."""


@dataclass(frozen=True)
class CurveBudget:
    """What a budget means for this study.

    Attributes:
        num_checkpoints: checkpoints per run, at steps S / 2^k (k = n-1 .. 0) for S steps.
        val_clips: the first this many samples of the val split are scored (of 200).
        test_clips: the first this many samples of the test split are scored (of 200).
        full_steps: every configuration trains this many steps (None: its cpu_steps).
        batch_size: samples per step of every configuration (None: its own).
        num_configs: only the first this many configurations run (None: all).
    """

    num_checkpoints: int
    val_clips: int
    test_clips: int
    full_steps: int | None = None
    batch_size: int | None = None
    num_configs: int | None = None


BUDGETS: dict[str, CurveBudget] = {
    "cpu": CurveBudget(num_checkpoints=6, val_clips=100, test_clips=200),
    "full": CurveBudget(
        num_checkpoints=6, val_clips=100, test_clips=200, full_steps=FULL_STEPS, batch_size=FULL_BATCH, num_configs=1
    ),
}


def checkpoint_steps(steps: int, num: int) -> list[int]:
    """Log-spaced checkpoints ending at `steps`: round(steps / 2^k) for k = num-1 .. 0, distinct, >= 1.

    Raises:
        ConfigError: steps or num below 1.
    """
    if steps < 1 or num < 1:
        raise ConfigError(f"checkpoint_steps(steps={steps}, num={num}): both must be >= 1")
    return sorted({max(1, round(steps / 2**k)) for k in range(num)})


@contextlib.contextmanager
def _quiet(name: str) -> Iterator[None]:
    """Hold a logger at ERROR: the K-ambiguity warnings of cluster.py are noise over hundreds of clips."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def score_clips(model: SubspaceNet, clips: Sequence[LabeledClip], k_max: int = 8) -> dict[str, float]:
    """Mean scores of a model on labelled clips (benchmark.evaluate_clips, silhouette K in 1..k_max).

    Returns:
        {"error": auto-K error, "error_true_k": error with the true K, "nmi": NMI with auto K,
        "correct_k": share of clips with the right K}, all fractions in [0, 1], and "clips".
    """
    from mosegpipe.evaluation.benchmark import evaluate_clips
    from mosegpipe.group.cluster import ClusterConfig

    with _quiet("mosegpipe.group.cluster"):
        rows = evaluate_clips(model, clips, ClusterConfig(k_max=k_max))
    return {
        "error": float(np.mean([r["error"] for r in rows])),
        "error_true_k": float(np.mean([r["error_true_k"] for r in rows])),
        "nmi": float(np.mean([r["nmi"] for r in rows])),
        "correct_k": float(np.mean([r["k_pred"] == r["k_true"] for r in rows])),
        "clips": len(rows),
    }


def _splits(budget: CurveBudget) -> dict[str, list[LabeledClip]]:
    from mosegpipe.synth.lce import lce_splits

    splits = lce_splits()
    return {
        "val": [splits["val"][i] for i in range(budget.val_clips)],
        "test": [splits["test"][i] for i in range(budget.test_clips)],
    }


def train_sampler() -> Sampler:
    """Uniform draws from the 8000-sample train split, each sample generated on its first draw.

    The same stream as the `lce` source's clip_sampler (one rng.integers(8000) per draw, the same
    sample per index) without generating all 8000 samples up front (4 s).
    """
    from mosegpipe.synth.lce import lce_splits

    train = lce_splits()["train"]
    made: dict[int, LabeledClip] = {}

    def draw(rng: np.random.Generator) -> LabeledClip:
        i = int(rng.integers(len(train)))
        if i not in made:
            made[i] = train[i]
        return made[i]

    return draw


def _kmeans_reference(req: StudyRequest, clips: Sequence[LabeledClip], chash: str) -> float:
    """Mean error of K-means on the raw (z-scored) points with the true K: the floor a model must beat."""
    from mosegpipe.evaluation.baselines import BASELINES
    from mosegpipe.evaluation.metrics import misclassification_error

    path = part_path(req, "kmeans-raw", ".json")
    payload = load_part(path, chash)
    if payload is None:
        fn = BASELINES["kmeans-raw"]
        errs = [misclassification_error(fn(c.traj, c.k), c.labels) for c in clips]
        payload = {"error_true_k": float(np.mean(errs)), "clips": len(errs)}
        save_part(path, chash, payload)
    return float(payload["error_true_k"])


def _device(budget: str, requested: str | None = None) -> str:
    """The request's device when it names one (checked), else cuda for --budget full when there is one."""
    import torch

    from mosegpipe.training.loop import resolve_device

    if requested is not None:
        return resolve_device(requested)
    return "cuda" if budget == "full" and torch.cuda.is_available() else "cpu"


def _run_config(
    cc: CurveConfig,
    budget_name: str,
    budget: CurveBudget,
    req: StudyRequest,
    clips: dict[str, list[LabeledClip]],
) -> tuple[list[dict[str, Any]], dict[str, float]]:
    """One configuration's curve: its checkpoint parts, training (resumed) only where some are missing.

    Returns:
        (one payload per checkpoint, {"train": seconds trained in this call, "eval": seconds scoring}).
    """
    import torch

    from mosegpipe.io.read import atomic_write
    from mosegpipe.training.loop import recipe_of, train_model

    say = req.progress or (lambda _msg: None)
    steps = budget.full_steps or cc.cpu_steps
    cfg = TrainConfig(**{**asdict(cc.train), "steps": steps})
    cps = checkpoint_steps(steps, budget.num_checkpoints)
    device = _device(budget_name, req.device)
    chash = _curve_hash(cc, cfg, cps, clips, req.k_max, device)
    paths = {s: part_path(req, f"{cc.name}__step{s:07d}", ".json") for s in cps}
    parts: dict[int, dict[str, Any] | None] = {s: load_part(paths[s], chash) for s in cps}
    missing = [s for s in cps if parts[s] is None]
    spent = {"train": 0.0, "eval": 0.0}
    if not missing:
        say(f"{cc.name}: all {len(cps)} checkpoints stored")
        return [p for p in parts.values() if p is not None], spent

    state_path = part_path(req, f"{cc.name}__state", ".pt")
    resume = _stored_state(state_path, chash, device, min(missing))
    if resume is not None:
        say(f"{cc.name}: resuming from step {resume.step}")

    def on_checkpoint(state: TrainState, model: SubspaceNet) -> None:
        t0 = time.perf_counter()
        if parts[state.step] is None:
            loss = state.history[-1]["loss"] if state.history else float("nan")
            payload: dict[str, Any] = {
                "config": cc.name,
                "step": state.step,
                "samples": state.step * cfg.batch_size,
                "train_seconds": round(state.seconds, 1),
                "loss": loss,
                **{split: score_clips(model, c, req.k_max) for split, c in clips.items()},
            }
            save_part(paths[state.step], chash, payload)
            parts[state.step] = payload
            say(
                f"{cc.name} step {state.step}: val {100 * payload['val']['error']:.2f} / "
                f"{100 * payload['val']['error_true_k']:.2f} %, test {100 * payload['test']['error']:.2f} / "
                f"{100 * payload['test']['error_true_k']:.2f} % (auto / true K), train {state.seconds:.0f} s"
            )
        if state.step == steps:
            model.save(
                req.out_dir / "models" / f"{cc.name}.pt", recipe={**recipe_of(cfg, {"lce": 1.0}), "name": cc.name}
            )
            state_path.unlink(missing_ok=True)
        else:
            with atomic_write(state_path) as tmp:
                torch.save({"config_hash": chash, "state": state.to_dict()}, tmp)
        spent["eval"] += time.perf_counter() - t0

    result = train_model(
        train_sampler(),
        cfg,
        cc.model,
        log_every=max(1, min(100, cps[0])),
        checkpoints=cps,
        on_checkpoint=on_checkpoint,
        resume=resume,
        stop_after=max(missing),
        device=device,
    )
    spent["train"] = result.seconds - (resume.seconds if resume is not None else 0.0)
    return [p for p in parts.values() if p is not None], spent


def _curve_hash(
    cc: CurveConfig, cfg: TrainConfig, cps: list[int], clips: dict[str, list[LabeledClip]], k_max: int, device: str
) -> str:
    """The hash a configuration's checkpoint parts and training state are stored under."""
    return stable_hash(
        {
            "study": "lce-curve",
            "v": PARTS_VERSION,
            "config": cc.to_dict(),
            "train": asdict(cfg),
            "checkpoints": cps,
            "clips": {k: len(v) for k, v in clips.items()},
            "k_max": k_max,
            "device": device,
        }
    )


def _stored_state(state_path: Path, chash: str, device: str, first_missing: int) -> TrainState | None:
    """The training state stored at `state_path` when it was saved under `chash` no later than the first
    missing checkpoint (None: none, another hash, or unreadable: training starts over)."""
    import torch

    from mosegpipe.training.loop import TrainState

    if not state_path.is_file():
        return None
    try:
        stored = torch.load(state_path, map_location=device, weights_only=True)
    except Exception:  # an unreadable state only costs a retraining
        stored = {}
    if stored.get("config_hash") == chash and int(stored["state"]["step"]) <= first_missing:
        return TrainState.from_dict(stored["state"])
    return None


def _fmt(x: float) -> str:
    return f"{100 * x:.2f}"


def _change(a: dict[str, Any], b: dict[str, Any], split: str, key: str) -> str:
    """'before -> after (difference)' of one score between two checkpoints (errors in %, NMI as is)."""
    x, y = a[split][key], b[split][key]
    if key == "nmi":
        return f"{x:.3f} -> {y:.3f} ({y - x:+.3f})"
    return f"{_fmt(x)} -> {_fmt(y)} ({100 * (y - x):+.2f})"


def _tables(
    configs: Sequence[CurveConfig], steps: dict[str, int], rows: list[dict[str, Any]], kmeans: float
) -> list[str]:
    head = [
        "| config | model | parameters | input norm | loss | lr (constant) | warm-up steps | batch | steps | why |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for cc in configs:
        m, t = cc.model, cc.train
        head.append(
            f"| {cc.name} | {m.num_blocks} blocks x {m.width} | {m.num_parameters:,} | {m.input_norm} | {t.loss} | "
            f"{t.lr:g} | {t.warmup} | {t.batch_size} | {steps[cc.name]} | {cc.why} |"
        )
    curve = [
        "| config | step | samples seen | train s | val error auto / true K (%) | val NMI | "
        "test error auto / true K (%) | test NMI | test correct K (%) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        v, t = r["val"], r["test"]
        curve.append(
            f"| {r['config']} | {r['step']} | {r['samples']:,} | {r['train_seconds']:.0f} | "
            f"{_fmt(v['error'])} / {_fmt(v['error_true_k'])} | {v['nmi']:.3f} | "
            f"{_fmt(t['error'])} / {_fmt(t['error_true_k'])} | {t['nmi']:.3f} | {100 * t['correct_k']:.1f} |"
        )
    last = [
        "| config | samples | val error true K (%) | test error true K (%) | test error auto K (%) | test NMI |",
        "|---|---|---|---|---|---|",
    ]
    for cc in configs:
        mine = [r for r in rows if r["config"] == cc.name]
        if len(mine) < 2:
            continue
        a, b = mine[-2], mine[-1]
        last.append(
            f"| {cc.name} | {a['samples']:,} -> {b['samples']:,} | {_change(a, b, 'val', 'error_true_k')} | "
            f"{_change(a, b, 'test', 'error_true_k')} | {_change(a, b, 'test', 'error')} | "
            f"{_change(a, b, 'test', 'nmi')} |"
        )
    return [
        "Configurations:",
        "",
        *head,
        "",
        "Scores at each checkpoint (one training run per configuration):",
        "",
        *curve,
        "",
        "The last doubling of the samples seen (the slope that decides budget or design):",
        "",
        *last,
        "",
        f"References on the test clips: K-means on the raw points with the true K {_fmt(kmeans)} %; "
        f"the paper {_fmt(PAPER_ERROR)} % (auto K), NMI {PAPER_NMI}.",
    ]


def plot_summary(configs: Sequence[CurveConfig], rows: list[dict[str, Any]], kmeans: float) -> Any:
    plt = pyplot_module()
    fig, (ax_err, ax_nmi) = plt.subplots(1, 2, figsize=(10.0, 4.0))
    for i, cc in enumerate(configs):
        mine = [r for r in rows if r["config"] == cc.name]
        if not mine:
            continue
        x = [r["samples"] for r in mine]
        colour = f"C{i}"
        ax_err.plot(x, [100 * r["test"]["error"] for r in mine], "o-", color=colour, label=f"{cc.name} (auto K)")
        ax_err.plot(
            x, [100 * r["test"]["error_true_k"] for r in mine], "s--", color=colour, label=f"{cc.name} (true K)"
        )
        ax_nmi.plot(x, [r["test"]["nmi"] for r in mine], "o-", color=colour, label=cc.name)
    ax_err.axhline(100 * kmeans, color="grey", lw=1, label="K-means on raw points (true K)")
    ax_err.axhline(100 * PAPER_ERROR, color="k", ls=":", lw=1, label="paper (auto K)")
    ax_nmi.axhline(PAPER_NMI, color="k", ls=":", lw=1, label="paper")
    for ax, what in ((ax_err, "test error (%)"), (ax_nmi, "test NMI (auto K)")):
        ax.set_xscale("log")
        ax.set_xlabel("training samples seen")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    ax_err.legend(fontsize=6)
    ax_nmi.legend(fontsize=7)
    fig.suptitle("LCE learning curves (one run per configuration, scored at checkpoints)", fontsize=9)
    fig.tight_layout()
    return fig


def run_lce_curve(
    study: Study,
    req: StudyRequest,
    configs: Sequence[CurveConfig] | None = None,
    budget: CurveBudget | None = None,
) -> StudyResult:
    """Learning curves on LCE: error (auto and true K) and NMI on val and test against samples seen.

    Args:
        study: the registry record.
        req: out_dir, budget, k_max and progress are used.
        configs: the configurations (None: CURVE_CONFIGS).
        budget: what req.budget means (None: BUDGETS[req.budget]); tests pass a tiny one.
    """
    budget_name = check_budget(req)
    device = _device(budget_name, req.device)  # checked before anything is computed
    budget = budget or BUDGETS[budget_name]
    configs = tuple(configs or CURVE_CONFIGS)[: budget.num_configs]
    if budget.batch_size is not None:
        configs = tuple(replace(cc, train=replace(cc.train, batch_size=budget.batch_size)) for cc in configs)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    clips = _splits(budget)
    kmeans = _kmeans_reference(req, clips["test"], stable_hash({"study": study.name, "test": len(clips["test"])}))
    rows: list[dict[str, Any]] = []
    seconds: dict[str, dict[str, float]] = {}
    steps = {cc.name: budget.full_steps or cc.cpu_steps for cc in configs}
    for cc in configs:
        mine, spent = _run_config(cc, budget_name, budget, req, clips)
        rows.extend(sorted(mine, key=lambda r: int(r["step"])))
        seconds[cc.name] = {k: round(v, 1) for k, v in spent.items()}
    wall, cpu = time.perf_counter() - t_start, time.process_time() - cpu_start
    notes = [
        budget_note(study, budget_name),
        f"Data: the LCE splits of synth/lce.py (seed 0); training samples drawn from the 8000-sample train split; "
        f"scored on the first {len(clips['val'])} val and first {len(clips['test'])} test samples (K = 4 each). "
        f"Error: misclassification (Hungarian matching), auto K by the silhouette rule (K in 1..{req.k_max}) and "
        "with the true K; NMI with auto K. Learning rate constant after a linear warm-up. Device: "
        f"{device}. This call: {wall:.0f} s wall, {cpu:.0f} s CPU (training and scoring; stored parts "
        "reused; train s in the table is wall time).",
    ]
    lines = [
        "# Study: lce-curve (LCE learning curves: budget or design?)",
        "",
        *notes,
        "",
        *_tables(configs, steps, rows, kmeans),
        "",
    ]
    table = "\n".join(lines)
    results = {
        "study": study.name,
        "budget": budget_name,
        "configs": [{**cc.to_dict(), "why": cc.why, "steps": steps[cc.name]} for cc in configs],
        "kmeans_raw_true_k": kmeans,
        "seconds": seconds,
        "wall_seconds": round(wall, 1),
        "cpu_seconds": round(cpu, 1),
        "rows": rows,
    }
    files = write_outputs(req, table, results, plot_summary(configs, rows, kmeans))
    models = [req.out_dir / "models" / f"{cc.name}.pt" for cc in configs]
    return StudyResult(table, results, files + [p for p in models if p.is_file()])
