"""Benchmark protocols: SubspaceNet and the classical baselines side by side on identical inputs.

Each protocol yields one row per test clip (error with automatic K and with the true K, NMI, chosen K,
time) and a summary; leave-one-out protocols train one model per fold and store each fold's rows as
soon as it finishes, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import csv
import hashlib
import io as _io
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from mosegpipe.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.evaluation.metrics import correct_k_rate, misclassification_error, nmi
from mosegpipe.io import atomic_write
from mosegpipe.model import SubspaceNet
from mosegpipe.training.loop import TrainConfig, recipe_of, train_model
from mosegpipe.training.recipes import build_sampler
from mosegpipe.types import LabeledClip

log = logging.getLogger(__name__)

PROTOCOLS = {
    "kt3d-test": "a given model on the 22 KT3DMoSeg test clips (frames 1-5), no training",
    "kt3d-loo": "KT3DMoSeg leave-one-sequence-out: train on 21 sequences, test on the held-out one's frames 1-5",
    "adelaide-test": "a given two-view model on the 19 AdelaideRMF pairs, no training",
    "adelaide-loo": "AdelaideRMF leave-one-pair-out: train on 18 pairs, test on the held-out one",
    "hopkins-test": "a given model on the 155 Hopkins155 sequences (first F frames), no training",
    "lce": "synthetic lines/circles/ellipses: train on the 8000-sample split (unless a model is given), test on 200",
}


@dataclass(frozen=True)
class EvalConfig:
    """What one `moseg eval` run does.

    Attributes:
        protocol: a key of PROTOCOLS.
        variant: kt3d-loo only: "vanilla" (one frames-1..5 clip per training sequence) or "augment"
            (every 5-frame window of the training sequences).
        frames: trajectory length F.
        baselines: names from baselines.BASELINES run on the same clips (true K and automatic K).
        cluster: automatic-K settings.
        train: per-fold training settings (LOO protocols, lce).
        synthetic_weight: LOO protocols: weight of on-the-fly synthetic clips mixed into each fold's
            training data (0 = benchmark data only).
        folds: only these held-out names (None = all).
    """

    protocol: str = "kt3d-test"
    variant: str = "vanilla"
    frames: int = 5
    baselines: tuple[str, ...] = ("kmeans-raw", "spectral-raw", "ssc")
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    synthetic_weight: float = 0.0
    folds: tuple[str, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["folds"] = list(self.folds) if self.folds is not None else None
        d["baselines"] = list(self.baselines)
        return d


def embed_clip(model: SubspaceNet, clip: LabeledClip) -> np.ndarray:
    """Embeds a clip, resampling its trajectories in time when its F differs from the model's."""
    from mosegpipe.types import Trajectories

    return model.embed(Trajectories(clip.traj, np.arange(clip.num_points, dtype=np.int64)))


def evaluate_clips(
    model: SubspaceNet | None,
    clips: Sequence[LabeledClip],
    cluster_cfg: ClusterConfig = ClusterConfig(),
    baselines: Sequence[str] = (),
) -> list[dict[str, Any]]:
    """Scores a model (and baselines) on labelled clips.

    Returns:
        One row per clip: name, num_points, k_true, k_pred, error (automatic K), error_true_k, nmi,
        seconds (embedding + automatic K), and `<baseline>@K` / `<baseline>@auto` errors.
    """
    from mosegpipe.evaluation.baselines import BASELINES

    unknown = [b for b in baselines if b not in BASELINES]
    if unknown:
        raise ValueError(f"unknown baseline(s) {unknown}; choose from {sorted(BASELINES)}")
    if model is not None and clips:
        # The first call pays one-off costs (allocator, sklearn import paths); keep them out of the timings.
        cluster_auto_k(embed_clip(model, clips[0]), cluster_cfg)
    rows = []
    for clip in clips:
        row: dict[str, Any] = {"name": clip.name, "num_points": clip.num_points, "k_true": clip.k}
        if model is not None:
            t0 = time.perf_counter()
            emb = embed_clip(model, clip)
            auto = cluster_auto_k(emb, cluster_cfg)
            row["seconds"] = time.perf_counter() - t0
            fixed = cluster_auto_k(emb, cluster_cfg, k=clip.k)
            row.update(
                k_pred=auto.k,
                error=misclassification_error(auto.labels, clip.labels),
                error_true_k=misclassification_error(fixed.labels, clip.labels),
                nmi=nmi(auto.labels, clip.labels),
            )
        for b in baselines:
            fn = BASELINES[b]
            row[f"{b}@K"] = misclassification_error(fn(clip.traj, clip.k), clip.labels)
            row[f"{b}@auto"] = misclassification_error(fn(clip.traj, None), clip.labels)
        rows.append(row)
    return rows


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean / median of every error column, correct-K rate and total time over the rows."""
    if not rows:
        return {}
    out: dict[str, Any] = {"num_clips": len(rows)}
    error_cols = [c for c in rows[0] if c.startswith("error") or "@" in c]
    for col in error_cols:
        vals = np.array([r[col] for r in rows if col in r], dtype=np.float64)
        out[col] = {"mean": float(vals.mean()), "median": float(np.median(vals))}
    if "k_pred" in rows[0]:
        out["correct_k"] = correct_k_rate([r["k_pred"] for r in rows], [r["k_true"] for r in rows])
        out["nmi"] = float(np.mean([r["nmi"] for r in rows]))
        out["seconds_total"] = float(sum(r["seconds"] for r in rows))
    return out


def format_table(rows: Sequence[dict[str, Any]], summary: dict[str, Any]) -> str:
    """A Markdown table: one row per clip (errors in %), then mean and median rows."""
    if not rows:
        return "(no rows)\n"
    cols = list(rows[0].keys())
    pct = {c for c in cols if c.startswith("error") or "@" in c}

    def fmt(col: str, val: Any) -> str:
        if col in pct:
            return f"{100 * val:.2f}"
        if col == "seconds":
            return f"{1000 * val:.1f}ms"
        if isinstance(val, float):
            return f"{val:.3f}"
        return str(val)

    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(fmt(c, r.get(c, "")) for c in cols) + " |")
    for stat in ("mean", "median"):
        cells = [f"**{stat}**"]
        for c in cols[1:]:
            cells.append(f"{100 * summary[c][stat]:.2f}" if c in pct else "")
        lines.append("| " + " | ".join(cells) + " |")
    extra = []
    if "correct_k" in summary:
        extra.append(
            f"correct K: {100 * summary['correct_k']:.2f} % · mean NMI {summary['nmi']:.3f} · "
            f"embedding + automatic K for all {summary['num_clips']} clips: {summary['seconds_total']:.3f} s"
        )
    return "\n".join(lines) + "\n\n" + "\n".join(extra) + "\n"


def write_results(
    out_dir: Path, rows: list[dict[str, Any]], summary: dict[str, Any], config: dict[str, Any], table: str | None = None
) -> str:
    """Writes results.json (config, summary, rows), results.csv (rows) and results.md (config + table)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = table if table is not None else format_table(rows, summary)
    with atomic_write(out_dir / "results.json") as tmp:
        Path(tmp).write_text(json.dumps({"config": config, "summary": summary, "rows": rows}, indent=2, default=float))
    buf = _io.StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r)) or ["name"]
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    writer.writerows(rows)
    with atomic_write(out_dir / "results.csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    md = f"# {config.get('protocol')}\n\n```json\n{json.dumps(config, indent=2)}\n```\n\n{table}"
    with atomic_write(out_dir / "results.md") as tmp:
        Path(tmp).write_text(md)
    return table


def _config_hash(config: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _test_clips(cfg: EvalConfig, data_root: Path) -> list[LabeledClip]:
    if cfg.protocol in ("kt3d-test", "kt3d-loo"):
        from mosegpipe.data.kt3dmoseg import kt3d_test_clips

        return kt3d_test_clips(data_root, frames=cfg.frames)
    if cfg.protocol in ("adelaide-test", "adelaide-loo"):
        from mosegpipe.data.adelaidermf import load_adelaide

        return load_adelaide(data_root)
    if cfg.protocol == "hopkins-test":
        from mosegpipe.data.hopkins155 import load_hopkins

        return load_hopkins(data_root, frames=cfg.frames or None)  # 0: all frames
    if cfg.protocol == "lce":
        from mosegpipe.synth.lce import lce_splits

        return list(lce_splits()["test"])
    raise ValueError(f"unknown protocol {cfg.protocol!r}; choose from {', '.join(PROTOCOLS)}")


def _sequence_of(clip: LabeledClip) -> str:
    return str(clip.meta.get("sequence", clip.name.split("/")[0]))


def run_protocol(
    cfg: EvalConfig,
    data_root: Path,
    out_dir: Path,
    model: SubspaceNet | None = None,
    init: SubspaceNet | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[list[dict[str, Any]], dict[str, Any], str]:
    """Runs a protocol and writes results.{json,csv,md} under out_dir.

    Args:
        cfg: the protocol and its settings.
        data_root: the benchmark folder.
        out_dir: where results (and per-fold files, for resuming) go.
        model: the model to test for "*-test" protocols (and "lce" without training).
        init: starting point of each LOO fold's training (e.g. a synthetic-only model); None = from scratch.
        progress: called with a one-line message after each fold / stage.

    Returns:
        (rows, summary, markdown table).
    """
    say = progress or (lambda _msg: None)
    if cfg.protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {cfg.protocol!r}; choose from {', '.join(PROTOCOLS)}")
    config = cfg.to_dict()
    config["init"] = None if init is None else getattr(init, "recipe", {}).get("name", "checkpoint")
    config["model"] = None if model is None else getattr(model, "recipe", {}).get("name", "checkpoint")
    clips = _test_clips(cfg, data_root)
    if cfg.folds is not None:
        wanted = set(cfg.folds)
        clips = [c for c in clips if _sequence_of(c) in wanted or c.name in wanted]
        if not clips:
            raise ValueError(f"no test clip matches --folds {sorted(wanted)}")
    loo = cfg.protocol.endswith("-loo") or (cfg.protocol == "lce" and model is None)
    if not loo:
        if model is None:
            raise ValueError(f"protocol {cfg.protocol} needs a model (--model or the shipped default)")
        rows = evaluate_clips(model, clips, cfg.cluster, cfg.baselines)
        summary = summarize(rows)
        return rows, summary, write_results(out_dir, rows, summary, config)

    fold_dir = out_dir / "folds"
    fold_dir.mkdir(parents=True, exist_ok=True)
    # Folds are keyed by what training depends on: re-running with other clustering settings or
    # baselines re-scores the stored fold models instead of training again.
    chash = _config_hash({k: v for k, v in config.items() if k not in ("cluster", "baselines", "folds")})
    rows = []
    if cfg.protocol == "lce":
        folds = [("all", clips, ("lce", 1.0))]
    elif cfg.protocol == "kt3d-loo":
        kt3d_source = "kt3d" if cfg.variant == "augment" else "kt3d-first"
        folds = [(_sequence_of(c), [c], (kt3d_source, 1.0)) for c in clips]
    else:
        folds = [(c.name, [c], ("adelaide", 1.0)) for c in clips]
    for held_out, test, source in folds:
        path = fold_dir / f"{held_out.replace('/', '_')}.json"
        model_path = path.with_suffix(".pt")
        if path.exists() and model_path.exists():
            stored = json.loads(path.read_text())
            if stored.get("config_hash") == chash:
                fold_rows = evaluate_clips(SubspaceNet.from_checkpoint(model_path), test, cfg.cluster, cfg.baselines)
                for r in fold_rows:
                    r["train_seconds"] = stored["recipe"].get("seconds")
                rows.extend(fold_rows)
                say(f"{held_out}: trained earlier, re-scored")
                continue
        sources: list[tuple[str, float]] = [source]
        if cfg.synthetic_weight > 0:
            sources.append(("synthetic-pair" if cfg.frames == 2 else "synthetic", cfg.synthetic_weight))
        exclude = () if cfg.protocol == "lce" else (held_out,)
        sampler, described = build_sampler(sources, data_root, cfg.frames, exclude=exclude, seed=cfg.train.seed)
        train_cfg = replace(cfg.train, frames=cfg.frames)
        result = train_model(sampler, train_cfg, init=init)
        fold_rows = evaluate_clips(result.model, test, cfg.cluster, cfg.baselines)
        for r in fold_rows:
            r["train_seconds"] = round(result.seconds, 1)
        recipe = recipe_of(train_cfg, described, result)
        result.model.save(model_path, recipe={**recipe, "name": f"{cfg.protocol}/{held_out}"})
        with atomic_write(path) as tmp:
            Path(tmp).write_text(json.dumps({"config_hash": chash, "recipe": recipe, "rows": fold_rows}))
        rows.extend(fold_rows)
        errs = ", ".join(
            f"{r['name']}: {100 * r['error']:.2f} % (K {r['k_pred']}/{r['k_true']})" for r in fold_rows[:3]
        )
        say(f"{held_out}: trained {result.steps_done} steps in {result.seconds:.0f} s; {errs}")
    summary = summarize(rows)
    return rows, summary, write_results(out_dir, rows, summary, config)
