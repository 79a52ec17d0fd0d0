"""Benchmark protocols: SubspaceNet and the classical baselines side by side on identical inputs.

Which clips a protocol reads and how it splits them into folds is its record in `protocols.PROTOCOLS`.

Each protocol yields one row per test clip (error with automatic K and with the true K, NMI, chosen K,
time) and a summary; leave-one-out protocols train one model per fold and store each fold's rows as
soon as it finishes, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mosegpipe.embed.model import SubspaceNet
from mosegpipe.errors import ConfigError
from mosegpipe.evaluation.folds import sequence_of
from mosegpipe.evaluation.metrics import misclassification_error, nmi
from mosegpipe.evaluation.report import summarize, write_results
from mosegpipe.group.cluster import ClusterConfig, cluster_auto_k
from mosegpipe.io.read import atomic_write
from mosegpipe.training.loop import TrainConfig
from mosegpipe.training.losses import LOSS_REVISIONS
from mosegpipe.training.run import train_sources
from mosegpipe.types import LabeledClip

if TYPE_CHECKING:
    from mosegpipe.evaluation.records import Protocol, Variant

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalConfig:
    """What one `moseg eval` run does.

    Attributes:
        protocol: the name of a benchmark protocol in protocols.PROTOCOLS.
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
    variant: Variant = "vanilla"
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
        raise ConfigError(f"unknown baseline(s) {unknown}; choose from {sorted(BASELINES)}")
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


def _config_hash(config: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_protocol(
    protocol: Protocol,
    cfg: EvalConfig,
    data_root: Path,
    out_dir: Path,
    model: SubspaceNet | None = None,
    init: SubspaceNet | None = None,
    progress: Callable[[str], None] | None = None,
    device: str = "cpu",
) -> tuple[list[dict[str, Any]], dict[str, Any], str]:
    """Runs a protocol and writes results.{json,csv,md} under out_dir.

    Args:
        protocol: the benchmark protocol's record (protocols.get_protocol(cfg.protocol)): its clips,
            training source and folds. Passed in, not looked up, so that this module does not import
            the registry that imports it.
        cfg: the protocol's name and its settings.
        data_root: the benchmark folder.
        out_dir: where results (and per-fold files, for resuming) go.
        model: the model to test for "*-test" protocols (and "lce" without training).
        init: starting point of each LOO fold's training (e.g. a synthetic-only model); None = from scratch.
        progress: called with a one-line message after each fold / stage.
        device: where the folds train (a checked name, see training.loop.resolve_device); scoring embeds there too.

    Returns:
        (rows, summary, markdown table).
    """
    say = progress or (lambda _msg: None)
    if protocol.name != cfg.protocol:
        raise ValueError(f"run_protocol: the record of {protocol.name!r} given for protocol {cfg.protocol!r}")
    if protocol.load_clips is None:
        raise ConfigError(f"{cfg.protocol} is an end-to-end protocol; run it with protocols.get_protocol(name).run")
    config = cfg.to_dict()
    config["init"] = None if init is None else getattr(init, "recipe", {}).get("name", "checkpoint")
    config["model"] = None if model is None else getattr(model, "recipe", {}).get("name", "checkpoint")
    clips = _test_clips(protocol.load_clips, cfg, data_root)
    # Leave-one-out protocols always train; a one-fold protocol (lce) trains only without a given model.
    trains = protocol.train_source is not None and (protocol.fold_key is not None or model is None)
    if not trains:
        if model is None:
            raise ConfigError(f"protocol {cfg.protocol} needs a model (--model or the shipped default)")
        rows = evaluate_clips(model, clips, cfg.cluster, cfg.baselines)
        summary = summarize(rows)
        return rows, summary, write_results(out_dir, rows, summary, config)

    fold_dir = out_dir / "folds"
    fold_dir.mkdir(parents=True, exist_ok=True)
    # Folds are keyed by what training depends on: re-running with other clustering settings or
    # baselines re-scores the stored fold models instead of training again.
    keyed = {k: v for k, v in config.items() if k not in ("cluster", "baselines", "folds")}
    if cfg.train.loss in LOSS_REVISIONS:  # fold models of an earlier definition of the loss are not reused
        keyed["loss_revision"] = LOSS_REVISIONS[cfg.train.loss]
    chash = _config_hash(keyed)
    rows = []
    assert protocol.train_source is not None
    source = (protocol.train_source(cfg.variant), 1.0)
    if protocol.fold_key is None:
        folds = [("all", clips)]
    else:
        # One clip per fold (each test clip is its own sequence or pair in these benchmarks).
        folds = [(protocol.fold_key(c), [c]) for c in clips]
    for held_out, test in folds:
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
        rows.extend(_train_fold(protocol, cfg, data_root, source, held_out, test, path, chash, init, device, say))
    summary = summarize(rows)
    return rows, summary, write_results(out_dir, rows, summary, config)


def _test_clips(
    load_clips: Callable[[Path, int], list[LabeledClip]], cfg: EvalConfig, data_root: Path
) -> list[LabeledClip]:
    """The protocol's test clips, only those of --folds when given (ConfigError when none is)."""
    clips = load_clips(data_root, cfg.frames)
    if cfg.folds is not None:
        wanted = set(cfg.folds)
        clips = [c for c in clips if sequence_of(c) in wanted or c.name in wanted]
        if not clips:
            raise ConfigError(f"no test clip matches --folds {sorted(wanted)}")
    return clips


def _train_fold(
    protocol: Protocol,
    cfg: EvalConfig,
    data_root: Path,
    source: tuple[str, float],
    held_out: str,
    test: list[LabeledClip],
    path: Path,
    chash: str,
    init: SubspaceNet | None,
    device: str,
    say: Callable[[str], None],
) -> list[dict[str, Any]]:
    """Trains the fold that holds `held_out` out, scores its test clips and stores both (the model
    beside `path`, the rows in it, under the config hash); returns the rows."""
    model_path = path.with_suffix(".pt")
    sources: list[tuple[str, float]] = [source]
    if cfg.synthetic_weight > 0:
        sources.append(("synthetic-pair" if cfg.frames == 2 else "synthetic", cfg.synthetic_weight))
    exclude = () if protocol.fold_key is None else (held_out,)
    train_cfg = replace(cfg.train, frames=cfg.frames)
    result, recipe = train_sources(sources, data_root, train_cfg, init=init, exclude=exclude, device=device)
    fold_rows = evaluate_clips(result.model, test, cfg.cluster, cfg.baselines)
    for r in fold_rows:
        r["train_seconds"] = round(result.seconds, 1)
    result.model.save(model_path, recipe={**recipe, "name": f"{cfg.protocol}/{held_out}"})
    with atomic_write(path) as tmp:
        Path(tmp).write_text(json.dumps({"config_hash": chash, "recipe": recipe, "rows": fold_rows}))
    errs = ", ".join(f"{r['name']}: {100 * r['error']:.2f} % (K {r['k_pred']}/{r['k_true']})" for r in fold_rows[:3])
    say(f"{held_out}: trained {result.steps_done} steps in {result.seconds:.0f} s; {errs}")
    return fold_rows
