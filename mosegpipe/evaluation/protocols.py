"""The protocol registry: every `moseg eval NAME`, benchmark and end-to-end, is one `Protocol` record.

A benchmark protocol feeds SubspaceNet a dataset's own labelled trajectories (`benchmark.run_protocol`:
SubspaceNet and the baselines side by side; leave-one-out folds train a model each). An end-to-end
protocol runs the whole pipeline on the dataset's frames or images and carries the ground truth over to
our own tracks (`e2e`). Adding a protocol is adding one record to `PROTOCOLS`:

    Protocol("kt3d-test", "...", default_frames=5, data="kt3dmoseg", run=run_benchmark,
             load_clips=_kt3d_clips)

This module imports nothing heavy: the record's functions import what they need when they run, so that
`moseg --help` and `moseg eval --help` stay fast.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast, get_args

from mosegpipe.errors import ConfigError, check_choice, lookup
from mosegpipe.evaluation.folds import sequence_of
from mosegpipe.evaluation.records import EndToEnd, EvalRequest, EvalResult, Protocol, Variant
from mosegpipe.types import KMethodName

__all__ = ["PROTOCOLS", "EndToEnd", "EvalRequest", "EvalResult", "Protocol", "Variant", "get_protocol"]

if TYPE_CHECKING:
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.pipeline import PipelineConfig
    from mosegpipe.training.loop import TrainConfig
    from mosegpipe.training.recipes import Recipe
    from mosegpipe.types import LabeledClip

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------------------------
# Runners: one for every benchmark protocol, one for every end-to-end protocol


def run_benchmark(protocol: Protocol, req: EvalRequest) -> EvalResult:
    """Runs a benchmark protocol (see benchmark.run_protocol) with the request's settings."""
    from dataclasses import replace

    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.embed.numpy_net import load_model
    from mosegpipe.evaluation.benchmark import EvalConfig, run_protocol
    from mosegpipe.group.cluster import ClusterConfig
    from mosegpipe.training.loop import TrainConfig, resolve_device, with_overrides

    if req.settings:
        raise ConfigError(
            f"--set {req.settings[0]}: --set applies to end-to-end protocols only ({protocol.name} is not one)"
        )
    if req.preset is not None:
        raise ConfigError(
            f"--preset {req.preset}: --preset applies to end-to-end protocols only ({protocol.name} is not one)"
        )
    variant = cast(Variant, check_choice("--variant", req.variant, get_args(Variant)))
    device = resolve_device(req.device)
    k_method = cast(KMethodName, req.k_method)  # ClusterConfig checks it
    f = req.frames if req.frames is not None else protocol.default_frames
    train_cfg = with_overrides(
        TrainConfig(frames=f, steps=500), steps=req.steps, batch_size=req.batch_size, lr=req.lr, loss=req.loss
    )
    cfg = EvalConfig(
        protocol=protocol.name,
        variant=variant,
        frames=f,
        baselines=req.baselines,
        cluster=replace(ClusterConfig(), method=k_method, k_max=req.k_max),
        train=train_cfg,
        synthetic_weight=req.synthetic_weight,
        folds=req.folds,
    )
    net = None
    if protocol.is_test_only:
        net = load_model(f, req.model)
    elif protocol.fold_key is None and req.model is not None:  # one fold: a given model is scored, not trained
        net = SubspaceNet.from_checkpoint(req.model)
    start = SubspaceNet.from_checkpoint(req.init) if req.init else None
    root = req.data_root if req.data_root is not None else Path(".")
    rows, summary, table = run_protocol(
        protocol, cfg, root, req.out_dir, model=net, init=start, progress=req.progress, device=device
    )
    return EvalResult(rows, summary, table)


def pipeline_config(req: EvalRequest, frames: int) -> PipelineConfig:
    """The pipeline settings an end-to-end protocol runs with: F frames, the request's options and settings; the mask
    networks they ask for loaded before any clip (`check_mask_networks`: one error, not a zero per clip)."""
    from mosegpipe.masks.learned.probability import check_mask_networks
    from mosegpipe.pipeline import PipelineConfig

    cfg = PipelineConfig.from_options(
        frames,
        k_method=req.k_method,
        k_max=req.k_max,
        method=req.method,
        points=req.points,
        rigid_check=req.rigid_check,
        mask={"method": req.mask_method} if req.mask_method is not None else None,
        preset=req.preset,
        settings=req.settings,
    )
    check_mask_networks(cfg.mask)
    return cfg


def run_end_to_end(protocol: Protocol, req: EvalRequest) -> EvalResult:
    """Runs an end-to-end protocol: the whole pipeline with the shipped (or given) model, scored and written."""

    from mosegpipe.embed.numpy_net import load_model
    from mosegpipe.evaluation.report import format_rows, summarize_rows, write_results

    assert protocol.end_to_end is not None, f"{protocol.name} has no end_to_end function"
    if req.folds:
        raise ConfigError(f"--folds {','.join(req.folds)}: {protocol.name} has no folds (it runs every clip)")
    f = req.frames or protocol.default_frames
    cfg = pipeline_config(req, f)
    net = load_model(f, req.model)
    rows = protocol.end_to_end(req.data_root, net, cfg, None, req.baselines or None)
    config = {
        "protocol": protocol.name,
        "frames": f,
        "k_method": req.k_method,
        "k_max": req.k_max,
        "rigid_check": req.rigid_check,
        "method": cfg.method,
        "points": cfg.tracker,
        "model": str(req.model or "shipped default"),
        **({"preset": req.preset} if req.preset is not None else {}),
        **({"settings": list(req.settings)} if req.settings else {}),
    }
    table = format_rows(rows)
    summary = summarize_rows(rows)
    write_results(req.out_dir, rows, summary, config, table)
    return EvalResult(rows, summary, table)


def run_davis_protocol(protocol: Protocol, req: EvalRequest) -> EvalResult:
    """DAVIS-2016 train clips (evaluation.davis): the pipeline's dense masks against the human masks of the
    main moving object, J and F per clip and over the dev / val / all clips; with any --baselines also
    the classical flow-homography reference on the same frames. `req.folds` picks clips by name.
    """
    from dataclasses import asdict

    from mosegpipe.embed.numpy_net import load_embedder
    from mosegpipe.evaluation.davis import DAVIS_MODES, MODES, format_table, pipeline_method, run_davis
    from mosegpipe.evaluation.report import write_results

    if req.data_root is None:
        raise ConfigError(f"{protocol.name} needs the benchmark data (--data-root)")
    mode = DAVIS_MODES[protocol.name]
    cfg = pipeline_config(req, req.frames or protocol.default_frames)
    load_embedder(MODES[mode] or cfg.frames, req.model)  # a checkpoint that cannot be used: refused before any clip
    methods: list[tuple[str, Any]] = [("pipeline", pipeline_method(cfg, req.model))]
    if req.baselines:
        methods.append(("flow-homography", "flow-homography"))
    rows: list[dict[str, Any]] = []
    tables, summary = [], {}
    for name, method in methods:
        report = run_davis(req.data_root, mode, method, clips=req.folds, threads=None, name=name)
        rows += [{"method": name, **asdict(r)} for r in report.rows]
        summary[name] = report.means
        tables.append(format_table(report))
        if req.progress is not None:
            req.progress(
                f"{name}: " + ", ".join(f"{p} J {m['j_mean']:.3f} F {m['f_mean']:.3f}" for p, m in report.means.items())
            )
    config = {
        "protocol": protocol.name,
        "mode": mode,
        "frames": cfg.frames,
        "mask_method": cfg.mask.method,
        "k_method": req.k_method,
        "k_max": req.k_max,
        "rigid_check": req.rigid_check,
        "method": cfg.method,
        "points": cfg.tracker,
        "model": str(req.model or "shipped default"),
        "clips": list(req.folds) if req.folds else "all",
        **({"preset": req.preset} if req.preset is not None else {}),
        **({"settings": list(req.settings)} if req.settings else {}),
    }
    table = "\n\n".join(tables)
    write_results(req.out_dir, rows, summary, config, table)
    return EvalResult(rows, summary, table)


def run_composite_protocol(protocol: Protocol, req: EvalRequest) -> EvalResult:
    """Composites of the DAVIS clips (evaluation.composite): J per object, correct K, track error, labels per
    object; `req.folds` picks a part (dev, the default; val; all) or composites by name."""
    from mosegpipe.evaluation.composite import run_composite

    return run_composite(protocol.name, req, pipeline_config(req, req.frames or protocol.default_frames))


def run_end_to_end_loo(protocol: Protocol, req: EvalRequest) -> EvalResult:
    """End to end, leave one out: per held-out sequence, train the protocol's recipe without it, then run
    the whole pipeline on it.

    Each fold trains `protocol.fold_recipe` exactly as written (the request's steps / batch size / lr /
    loss override it) from the recipe's init checkpoint (`req.init`, else `out_dir/<init>.pt`, trained
    first by its own recipe when missing; no init recipe reads the protocol's dataset). The held-out
    name is excluded from every source, so its frames and tracks never reach training. Fold models and
    rows are kept in out_dir/folds/ under a hash of what training depends on: an interrupted run
    resumes, a re-run with other clustering settings or baselines re-scores without training.
    """
    import hashlib
    import json
    from dataclasses import asdict

    from mosegpipe.evaluation.report import format_rows, summarize_rows, write_results
    from mosegpipe.training.loop import resolve_device
    from mosegpipe.training.recipes import get_recipe
    from mosegpipe.training.run import TrainOverrides

    assert protocol.end_to_end is not None and protocol.fold_recipe is not None and protocol.fold_names is not None
    if req.data_root is None:
        raise ConfigError(f"{protocol.name} needs the benchmark data (--data-root)")
    recipe = get_recipe(req.recipe or protocol.fold_recipe)
    if recipe.train.frames != protocol.default_frames:
        raise ConfigError(
            f"--recipe {recipe.name}: trains {recipe.train.frames}-frame models, {protocol.name} needs "
            f"{protocol.default_frames} frames"
        )
    train_cfg = TrainOverrides(steps=req.steps, batch_size=req.batch_size, lr=req.lr, loss=req.loss).apply(recipe.train)
    device = resolve_device(req.device)
    cfg = pipeline_config(req, train_cfg.frames)
    say = req.progress or (lambda _msg: None)
    names = protocol.fold_names(req.data_root)
    if req.folds is not None:
        unknown = sorted(set(req.folds) - set(names))
        if unknown:
            raise ConfigError(f"--folds {', '.join(unknown)}: not in {protocol.name} (choose from {', '.join(names)})")
        names = [n for n in names if n in set(req.folds)]

    init, init_path, init_hash = _fold_init(recipe, req, req.data_root, device, say)
    training = {"recipe": recipe.to_dict(), "train": asdict(train_cfg), "init_sha256": init_hash}
    chash = hashlib.sha256(json.dumps(training, sort_keys=True, default=str).encode()).hexdigest()[:16]

    fold_dir = req.out_dir / "folds"
    rows: list[dict[str, Any]] = []
    for name in names:
        model, seconds, trained = _fold_model(
            protocol, req.data_root, name, fold_dir, chash, training, recipe, train_cfg, init, init_path, device
        )
        fold_rows = protocol.end_to_end(req.data_root, model, cfg, [name], req.baselines)
        for r in fold_rows:
            r["train_seconds"] = seconds
        rows.extend(fold_rows)
        errs = ", ".join(f"{100 * r['error']:.2f} % (K {r['k_pred']}/{r['k_true']})" for r in fold_rows)
        say(f"{name}: {trained}; {errs}")
    config = {
        "protocol": protocol.name,
        "fold_recipe": recipe.name,
        "train": asdict(train_cfg),
        "init": str(init_path) if init_path else None,
        "k_method": req.k_method,
        "k_max": req.k_max,
        "rigid_check": req.rigid_check,
        "baselines": list(req.baselines),
        "folds": names,
    }
    table = format_rows(rows)
    summary = summarize_rows(rows)
    write_results(req.out_dir, rows, summary, config, table)
    return EvalResult(rows, summary, table)


def _fold_init(
    recipe: Recipe, req: EvalRequest, data_root: Path, device: Any, say: Callable[[str], None]
) -> tuple[SubspaceNet | None, Path | None, str | None]:
    """The folds' starting model, its checkpoint and the checkpoint's hash (all None: from scratch):
    `req.init`, else out_dir/<recipe.init>.pt, trained first by its own recipe when missing."""
    import hashlib

    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.training.run import train_recipe

    init: SubspaceNet | None = None
    init_path: Path | None = req.init
    if init_path is None and recipe.init is not None:
        init_path = req.out_dir / f"{recipe.init}.pt"
        if not (init_path.is_file() and SubspaceNet.from_checkpoint(init_path).recipe.get("name") == recipe.init):
            say(f"training the folds' starting point {recipe.init} -> {init_path}")
            train_recipe(recipe.init, init_path, data_root, device=device)
    init_hash = None
    if init_path is not None:
        init = SubspaceNet.from_checkpoint(init_path)
        init_hash = hashlib.sha256(init_path.read_bytes()).hexdigest()[:16]
    return init, init_path, init_hash


def _fold_model(
    protocol: Protocol,
    data_root: Path,
    name: str,
    fold_dir: Path,
    chash: str,
    training: dict[str, Any],
    recipe: Recipe,
    train_cfg: TrainConfig,
    init: SubspaceNet | None,
    init_path: Path | None,
    device: Any,
) -> tuple[SubspaceNet, Any, str]:
    """The model of the fold that holds `name` out, its training seconds and a word on it: read back
    from fold_dir when trained earlier with the same config hash, else trained now and stored there."""
    import json

    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.io.read import write_text
    from mosegpipe.training.run import train_sources

    meta_path, model_path = fold_dir / f"{name}.json", fold_dir / f"{name}.pt"
    stored = json.loads(meta_path.read_text()) if meta_path.is_file() and model_path.is_file() else {}
    if stored.get("config_hash") == chash:
        model = SubspaceNet.from_checkpoint(model_path)
        seconds = stored.get("train_seconds")
        trained = "trained earlier"
    else:
        result, rec = train_sources(
            recipe.sources,
            data_root,
            train_cfg,
            model_cfg=recipe.model,
            init=init,
            exclude=(name,),
            device=device,
        )
        model, seconds = result.model, round(result.seconds, 1)
        rec.update(name=f"{protocol.name}/{name}", init=str(init_path) if init_path else None, excluded=[name])
        model.save(model_path, recipe=rec)
        write_text(meta_path, json.dumps({"config_hash": chash, "train_seconds": seconds, "training": training}))
        trained = f"trained {result.steps_done} steps in {seconds:.0f} s"
    return model, seconds, trained


# ---------------------------------------------------------------------------------------------
# What each protocol reads


def _kt3d_clips(data_root: Path, frames: int) -> list[LabeledClip]:
    from mosegpipe.data.kt3dmoseg import kt3d_test_clips

    return kt3d_test_clips(data_root, frames=frames)


def _adelaide_clips(data_root: Path, frames: int) -> list[LabeledClip]:
    from mosegpipe.data.adelaidermf import load_adelaide

    return load_adelaide(data_root)


def _hopkins_clips(data_root: Path, frames: int) -> list[LabeledClip]:
    from mosegpipe.data.hopkins155 import load_hopkins

    return load_hopkins(data_root, frames=frames or None)  # 0: all frames


def _lce_clips(data_root: Path, frames: int) -> list[LabeledClip]:
    from mosegpipe.synth.lce import lce_splits

    return list(lce_splits()["test"])


def _clip_name(clip: LabeledClip) -> str:
    return clip.name


def _benchmark_rows(function: str) -> EndToEnd:
    """An end-to-end adapter: `evaluation.e2e.<function>` on the benchmark folder (imported when it runs)."""

    def rows(
        data_root: Path | None,
        model: SubspaceNet | None,
        cfg: PipelineConfig,
        names: Sequence[str] | None = None,
        baselines: Sequence[str] | None = None,
    ) -> list[dict[str, Any]]:
        from mosegpipe.evaluation import e2e

        assert data_root is not None
        row_fn: Callable[..., list[dict[str, Any]]] = getattr(e2e, function)
        return row_fn(data_root, model, cfg, names=names, baselines=baselines)

    return rows


_kt3d_video = _benchmark_rows("kt3d_video_rows")
_adelaide_pairs = _benchmark_rows("adelaide_pair_rows")


def _kt3d_names(data_root: Path) -> list[str]:
    from mosegpipe.data.kt3dmoseg import list_kt3d_sequences

    return list_kt3d_sequences(data_root)


def _adelaide_names(data_root: Path) -> list[str]:
    from mosegpipe.data.adelaidermf import list_adelaide

    return list_adelaide(data_root)


def _rendered(
    data_root: Path | None,
    model: SubspaceNet | None,
    cfg: PipelineConfig,
    names: Sequence[str] | None = None,
    baselines: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """`rendered_rows` with its defaults; data_root, names and baselines are not used (the clips are rendered)."""
    from mosegpipe.evaluation.e2e import rendered_rows

    return rendered_rows(model, cfg, frames=cfg.frames)


def _rendered_long(
    data_root: Path | None,
    model: SubspaceNet | None,
    cfg: PipelineConfig,
    names: Sequence[str] | None = None,
    baselines: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """`long_rendered_rows` with its defaults (4 clips of 120 frames at 640x480, one camera cut each)."""
    from mosegpipe.evaluation.e2e import long_rendered_rows

    return long_rendered_rows(model, cfg)


def _kt3d_source(variant: str) -> str:
    return "kt3d" if variant == "augment" else "kt3d-first"


_PROTOCOLS: Sequence[Protocol] = (
    Protocol(
        "kt3d-test",
        "a given model on the 22 KT3DMoSeg test clips (frames 1-5), no training",
        default_frames=5,
        data="kt3dmoseg",
        run=run_benchmark,
        load_clips=_kt3d_clips,
    ),
    Protocol(
        "kt3d-loo",
        "KT3DMoSeg leave-one-sequence-out: train on 21 sequences, test on the held-out one's frames 1-5",
        default_frames=5,
        data="kt3dmoseg",
        run=run_benchmark,
        load_clips=_kt3d_clips,
        train_source=_kt3d_source,
        fold_key=sequence_of,
    ),
    Protocol(
        "adelaide-test",
        "a given two-view model on the 19 AdelaideRMF pairs, no training",
        default_frames=2,
        data="adelaidermf",
        run=run_benchmark,
        load_clips=_adelaide_clips,
    ),
    Protocol(
        "adelaide-loo",
        "AdelaideRMF leave-one-pair-out: train on 18 pairs, test on the held-out one",
        default_frames=2,
        data="adelaidermf",
        run=run_benchmark,
        load_clips=_adelaide_clips,
        train_source=lambda _variant: "adelaide",
        fold_key=_clip_name,
    ),
    Protocol(
        "hopkins-test",
        "a given model on the 155 Hopkins155 sequences (first F frames), no training",
        default_frames=5,
        data="hopkins155",
        run=run_benchmark,
        load_clips=_hopkins_clips,
    ),
    Protocol(
        "lce",
        "synthetic lines/circles/ellipses: train on the 8000-sample split (unless a model is given), test on 200",
        default_frames=1,
        data=None,
        run=run_benchmark,
        load_clips=_lce_clips,
        train_source=lambda _variant: "lce",
    ),
    Protocol(
        "kt3d-video",
        "end to end: KLT tracks on the KT3DMoSeg frames, labels transferred from the ground truth",
        default_frames=5,
        data="kt3dmoseg",
        run=run_end_to_end,
        kind="end-to-end",
        end_to_end=_kt3d_video,
    ),
    Protocol(
        "adelaide-pairs",
        "end to end: SIFT matches on the AdelaideRMF images, labels transferred from the ground truth",
        default_frames=2,
        data="adelaidermf",
        run=run_end_to_end,
        kind="end-to-end",
        end_to_end=_adelaide_pairs,
    ),
    Protocol(
        "kt3d-video-loo",
        "end to end, leave one sequence out: each fold trains clip-f5 without the held-out sequence, "
        "then KLT tracks on its frames 1-5",
        default_frames=5,
        data="kt3dmoseg",
        run=run_end_to_end_loo,
        kind="end-to-end",
        end_to_end=_kt3d_video,
        fold_recipe="clip-f5",
        fold_names=_kt3d_names,
    ),
    Protocol(
        "adelaide-pairs-loo",
        "end to end, leave one pair out: each fold trains pair-f2 without the held-out pair, then SIFT on its images",
        default_frames=2,
        data="adelaidermf",
        run=run_end_to_end_loo,
        kind="end-to-end",
        end_to_end=_adelaide_pairs,
        fold_recipe="pair-f2",
        fold_names=_adelaide_names,
    ),
    Protocol(
        "rendered",
        "end to end: rendered clips, mask J and boundary F against exact masks",
        default_frames=5,
        data=None,
        run=run_end_to_end,
        kind="end-to-end",
        end_to_end=_rendered,
    ),
    Protocol(
        "rendered-long",
        "end to end, whole-video mode: long rendered clips with a camera cut, video-level J / F and labels per object",
        default_frames=5,
        data=None,
        run=run_end_to_end,
        kind="end-to-end",
        end_to_end=_rendered_long,
    ),
)

_PROTOCOLS = (
    *_PROTOCOLS,
    Protocol(
        "davis",
        "DAVIS-2016 train clips, whole-video mode: dense masks vs the moving object's human masks, J and F, dev / val",
        default_frames=5,
        data="davis2016-train",
        run=run_davis_protocol,
        kind="end-to-end",
    ),
    Protocol(
        "davis-clip5",
        "DAVIS-2016 train clips, the first 5 frames of each as one clip: J and F, dev / val",
        default_frames=5,
        data="davis2016-train",
        run=run_davis_protocol,
        kind="end-to-end",
    ),
)

_PROTOCOLS = (
    *_PROTOCOLS,
    *(
        Protocol(
            name,
            f"composites of the DAVIS clips (2-4 objects moved over other clips), {what}: J per object, correct K, "
            "track error, labels per object; --folds dev (default) / val / names",
            default_frames=5,
            data="davis2016-train",
            run=run_composite_protocol,
            kind="end-to-end",
        )
        for name, what in (("composite", "whole-video mode"), ("composite-clip5", "the first 5 frames"))
    ),
)

PROTOCOLS: dict[str, Protocol] = {p.name: p for p in _PROTOCOLS}
"""Every protocol by name, benchmark protocols first (the order of --help and of error messages)."""


def get_protocol(name: str) -> Protocol:
    """The protocol called `name`.

    Raises:
        ConfigError: no protocol has that name; the message lists them.
    """
    return lookup(PROTOCOLS, name, "protocol")
