"""moseg train (a checkpoint from a named recipe), moseg eval (a benchmark protocol) and moseg study (a
study of the paper), with the choices they offer, built from the library's registries and vocabularies (mosegpipe.types)."""

from __future__ import annotations

import os
import sys
import tempfile
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeAlias, get_args

import typer

from mosegpipe.cli.app import friendly, setup_run
from mosegpipe.cli.common import check_model_path
from mosegpipe.cli.options import (
    K_MAX,
    K_METHOD,
    RIGID_CHECK,
    DataRoot,
    Device,
    KMax,
    KMethod,
    LearningRate,
    MaskMethodChoice,
    MethodChoice,
    ModelOpt,
    PointsChoice,
    RigidCheck,
    Seed,
    Verbose,
    choice_type,
    enum_value,
    learning_rate,
    resolve_data_root,
)
from mosegpipe.cli.options import PresetChoice as PipelinePresetChoice
from mosegpipe.errors import InputError
from mosegpipe.evaluation.protocols import PROTOCOLS, Variant
from mosegpipe.studies import STUDIES, Budget
from mosegpipe.types import BASELINE_NAMES, LOSS_NAMES, MASKNET_PRESET, RECIPE_NAMES, TRAIN_PRESETS, WHICHNET_PRESET

if TYPE_CHECKING:
    PresetChoice: TypeAlias = StrEnum
    TrainPresetChoice: TypeAlias = StrEnum
    LossChoice: TypeAlias = StrEnum
    ProtocolChoice: TypeAlias = StrEnum
    VariantChoice: TypeAlias = StrEnum
    StudyChoice: TypeAlias = StrEnum
    BudgetChoice: TypeAlias = StrEnum
else:  # the registries and vocabularies of the library (light modules: they import nothing heavy)
    PresetChoice = choice_type("PresetChoice", RECIPE_NAMES)  # eval --recipe
    TrainPresetChoice = choice_type("TrainPresetChoice", TRAIN_PRESETS)  # train --preset
    LossChoice = choice_type("LossChoice", LOSS_NAMES)  # --loss
    ProtocolChoice = choice_type("ProtocolChoice", list(PROTOCOLS))  # eval PROTOCOL
    VariantChoice = choice_type("VariantChoice", get_args(Variant))  # eval --variant
    StudyChoice = choice_type("StudyChoice", list(STUDIES))  # study NAME
    BudgetChoice = choice_type("BudgetChoice", get_args(Budget))  # study --budget


def _protocol_help() -> str:
    """The protocol names from the registry: benchmark ones, then end-to-end ones."""
    bench = [p.name for p in PROTOCOLS.values() if p.kind == "benchmark"]
    e2e = [p.name for p in PROTOCOLS.values() if p.kind == "end-to-end"]
    return f"{', '.join(bench)}; end to end: {', '.join(e2e)}."


@friendly
def train(
    preset: Annotated[
        TrainPresetChoice,
        typer.Option(
            "--preset",
            help="Named recipe: clip-f5 (the shipped 5-frame model), clip-f5-rendered, clip-f5-davis, "
            "clip-f5-variety, clip-f5-composites, clip-f5-near (clip-f5 with other sources mixed in: experiments, "
            "docs/TRAINING.md), base-f5 (its starting point), synthetic-f5, "
            "pair-f2 (the shipped two-view model), synthetic-f2, lce (the paper's LCE study); masknet (the shipped "
            "mask network of --mask-method learned; --steps, --batch-size, --lr, --seed apply), whichnet (the shipped "
            "per-motion network of --set mask.which=learned; the same options apply).",
        ),
    ] = TrainPresetChoice(TRAIN_PRESETS[0]),
    out: Annotated[Path, typer.Option("--out", "-o", help="Checkpoint file to write.")] = Path("runs/model.pt"),
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Override the recipe's step count.")] = None,
    batch_size: Annotated[
        int | None, typer.Option("--batch-size", min=1, help="Override the recipe's clips per training step.")
    ] = None,
    lr: LearningRate = None,
    loss: Annotated[
        LossChoice | None,
        typer.Option(
            "--loss",
            help="Override the recipe's loss: mimi (the paper's MaxInterMinIntra), l2, l2-balanced (every pair of groups "
            "weighted alike) or ce (affinity losses), "
            "triplet, lifted or facility (the metric-learning baselines of the paper's Table 2), "
            "mimi-point (MaxInterMinIntra with the worst point's spread as its intra term), "
            "mimi-mean (with the widest group's mean squared spread).",
        ),
    ] = None,
    seed: Seed = None,
    init: Annotated[Path | None, typer.Option("--init", help="Fine-tune from this checkpoint.")] = None,
    exclude: Annotated[
        str | None, typer.Option("--exclude", help="Comma-separated source names to leave out (leave-one-dataset-out).")
    ] = None,
    time_budget: Annotated[float | None, typer.Option("--time-budget", help="Stop after this many seconds.")] = None,
    data_root: DataRoot = None,
    device: Device = None,
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads for torch.")] = 2,
    verbose: Verbose = False,
) -> None:
    """Train a SubspaceNet checkpoint from a named recipe (real tracks or trajectories and synthetic data, as it mixes them).

    Without --init a recipe starts from its own starting recipe (clip-f5 from base-f5, pair-f2 from
    synthetic-f2), trained first into the --out folder when its checkpoint is not there yet.
    """
    _check_checkpoint_out(out)
    setup_run(threads, verbose)
    from mosegpipe.training.loop import resolve_device

    where = resolve_device(device or "cpu")
    if enum_value(preset) in (MASKNET_PRESET, WHICHNET_PRESET):
        overrides = {"steps": steps, "batch_size": batch_size, "lr": lr, "seed": seed}
        unused = (loss, init, exclude, time_budget)
        _train_mask_networks(enum_value(preset), out, resolve_data_root(data_root), overrides, unused, where)
        return
    from mosegpipe.training.run import TrainOverrides, needs_data, train_recipe

    preset = enum_value(preset)
    dropped = {s.strip() for s in exclude.split(",")} if exclude else set()
    root = resolve_data_root(data_root) if needs_data(preset, dropped) else data_root
    result = train_recipe(
        preset,
        out,
        root,
        init=init,
        overrides=TrainOverrides(
            steps=steps, batch_size=batch_size, lr=lr, loss=enum_value(loss), seed=seed, time_budget_s=time_budget
        ),
        exclude_sources=dropped,
        command=" ".join(["moseg", *sys.argv[1:]]),
        device=where,
        on_start=lambda recipe, cfg, described: typer.echo(
            f"training {recipe.name}: {cfg.steps} steps × {cfg.batch_size} clips, sources {described}"
        ),
        on_log=lambda e: typer.echo(
            f"step {int(e['step']):>6}  loss {e['loss']:.4f}  lr {e['lr']:.2e}  {e['seconds']:.0f} s"
        ),
    )
    typer.echo(f"wrote {out} ({result.steps_done} steps, {result.seconds:.0f} s)")


def _check_checkpoint_out(out: Path) -> None:
    """train --out, before any data is read: a file name (not a folder) whose folder exists or can be made,
    and can be written."""
    if out.is_dir():
        raise InputError(f"--out {out}: a folder; give the checkpoint's file name (e.g. {out / 'model.pt'})")
    folder = out.absolute().parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"--out {out}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK) or (out.exists() and not os.access(out, os.W_OK)):
        raise InputError(f"--out {out}: cannot write there ({folder} is read-only)")
    try:  # what access(2) cannot tell: a read-only file system, or /proc, for root
        os.rmdir(tempfile.mkdtemp(prefix=".moseg-train-", dir=folder))
    except OSError as exc:
        raise InputError(f"--out {out}: cannot write there ({folder}: {exc.strerror})") from None


def _train_mask_networks(
    preset: str,
    out: Path,
    root: Path,
    overrides: dict[str, int | float | None],
    unused: tuple[object, ...],
    device: str,
) -> None:
    """train --preset masknet / whichnet: the mask network's recipe (mosegpipe.training.masks.masknet) or the
    per-motion network's (mosegpipe.training.masks.whichnet), with the overrides given (--steps, --batch-size,
    --lr, --seed), on `device` (resolved)."""
    if any(u is not None for u in unused):
        raise InputError(f"train --preset {preset}: --loss, --init, --exclude and --time-budget do not apply")
    from dataclasses import replace

    command = " ".join(["moseg", *sys.argv[1:]])
    given: dict[str, Any] = {k: v for k, v in overrides.items() if v is not None}
    recipe: Any
    trainer: Any
    if preset == WHICHNET_PRESET:
        from mosegpipe.training.masks.whichnet import WhichTrainConfig as recipe
        from mosegpipe.training.masks.whichnet import train_whichnet as trainer

        score = "held-out accuracy {held_out_j:.3f}"
        done = "step {chosen_step}, held-out accuracy {held_out_accuracy}, nearest track {nearest_track_accuracy}"
    else:
        from mosegpipe.training.masks.masknet import MaskTrainConfig as recipe
        from mosegpipe.training.masks.masknet import train_masknet as trainer

        score = "held-out J {held_out_j:.3f} (threshold {threshold})"
        done = "step {chosen_step}, threshold {threshold}, held-out J {held_out_j}"
    cfg = replace(recipe(), **given)
    typer.echo(f"training {preset}: {cfg.steps} steps × {cfg.batch_size} crops")
    record = trainer(
        out,
        root,
        cfg,
        command,
        device=device,
        on_log=lambda e: typer.echo(
            f"step {int(e['step']):>6}  loss {e['loss']:.4f}  {score.format(**e)}  {e['cpu_s']:.0f} CPU s"
        ),
    )
    typer.echo(f"wrote {out} ({done.format(**record)})")


@friendly
def eval_(
    protocol: Annotated[ProtocolChoice, typer.Argument(help=_protocol_help())],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (results.md/csv/json; per-fold files to resume).")
    ],
    model: ModelOpt = None,
    variant: Annotated[
        VariantChoice,
        typer.Option(
            "--variant", help="kt3d-loo: vanilla (the paper's protocol) or augment (with track augmentation)."
        ),
    ] = VariantChoice(get_args(Variant)[0]),
    frames: Annotated[
        int | None,
        typer.Option(
            "--frames",
            "-f",
            help="Trajectory length (default: 5; 2 for adelaide; hopkins-test 0 = all frames, resampled to the model's).",
        ),
    ] = None,
    init: Annotated[Path | None, typer.Option("--init", help="LOO folds start from this checkpoint.")] = None,
    recipe: Annotated[
        PresetChoice | None,
        typer.Option(
            "--recipe",
            help="kt3d-video-loo / adelaide-pairs-loo: the recipe each fold trains, one of "
            f"{', '.join(c.value for c in PresetChoice)} (default: the shipped one).",
        ),
    ] = None,
    steps: Annotated[int | None, typer.Option("--steps", min=1, help="Training steps per fold.")] = None,
    batch_size: Annotated[
        int | None, typer.Option("--batch-size", min=1, help="Clips per training step of each fold.")
    ] = None,
    lr: Annotated[
        float | None, typer.Option("--lr", callback=learning_rate, help="Learning rate of each fold (> 0).")
    ] = None,
    loss: Annotated[
        LossChoice | None,
        typer.Option(
            "--loss",
            help=f"Per-fold training loss: {', '.join(c.value for c in LossChoice)} (default: l2; see 'moseg train "
            "--help').",
        ),
    ] = None,
    synthetic_weight: Annotated[
        float, typer.Option("--synthetic-weight", help="LOO: weight of synthetic clips mixed into each fold.")
    ] = 0.0,
    baselines: Annotated[
        str,
        typer.Option(
            "--baselines",
            help=f"Comma-separated baselines from {', '.join(BASELINE_NAMES)} ('' for none); davis, davis-clip5: "
            "any adds the flow-homography reference.",
        ),
    ] = ",".join(BASELINE_NAMES),
    folds: Annotated[str | None, typer.Option("--folds", help="Comma-separated held-out names (default: all).")] = None,
    k_method: KMethod = K_METHOD,
    k_max: KMax = K_MAX,
    rigid_check: RigidCheck = RIGID_CHECK,
    mask_method: Annotated[
        MaskMethodChoice | None,
        typer.Option(
            "--mask-method",
            help=f"End-to-end protocols: the dense-mask method, {', '.join(c.value for c in MaskMethodChoice)} "
            "(default: the pipeline's).",
        ),
    ] = None,
    method: Annotated[
        MethodChoice | None,
        typer.Option(
            "--method",
            help="End-to-end protocols: how tracks become motions, subspacenet, geometric or joint (default: the pipeline's).",
        ),
    ] = None,
    points: Annotated[
        PointsChoice | None,
        typer.Option(
            "--points",
            help="End-to-end protocols (clips): where the points come from, klt, flow or klt+flow (default: the "
            "pipeline's).",
        ),
    ] = None,
    pipeline_preset: Annotated[
        PipelinePresetChoice | None,
        typer.Option(
            "--preset",
            help="End-to-end protocols: a named preset of the pipeline, best, balanced or fast (default: the "
            "pipeline's, best); --set applies after it.",
        ),
    ] = None,
    settings: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="End-to-end protocols: change a pipeline setting by its dotted path, e.g. --set "
            "mask.motion.fb_weight=0.5 (repeatable; the fields of PipelineConfig, values as JSON).",
        ),
    ] = None,
    data_root: DataRoot = None,
    device: Device = None,
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads.")] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a benchmark protocol: per-clip table, mean/median error, NMI, correct K, time, baselines."""
    setup_run(threads, verbose)
    from mosegpipe.evaluation.protocols import EvalRequest, get_protocol

    proto = get_protocol(enum_value(protocol))
    k_method = enum_value(k_method)
    request = EvalRequest(
        out_dir=out,
        data_root=resolve_data_root(data_root) if proto.data else data_root,
        model=model,
        init=init,
        frames=frames,
        variant=enum_value(variant),
        recipe=enum_value(recipe),
        steps=steps,
        batch_size=batch_size,
        lr=lr,
        loss=enum_value(loss),
        synthetic_weight=synthetic_weight,
        baselines=tuple(b for b in baselines.split(",") if b),
        folds=_names(folds),
        k_method=k_method,
        k_max=k_max,
        rigid_check=rigid_check,
        mask_method=enum_value(mask_method) if mask_method is not None else None,
        method=enum_value(method) if method is not None else None,
        points=enum_value(points) if points is not None else None,
        preset=enum_value(pipeline_preset),
        settings=tuple(settings or ()),
        device=device or "cpu",
        progress=typer.echo,
    )
    result = proto.run(proto, request)
    typer.echo(result.table)
    typer.echo(f"wrote {out}/results.md, results.csv, results.json")


def _names(text: str | None) -> tuple[str, ...] | None:
    """--folds: the comma-separated names, each once (a name given twice would be run and counted twice) and
    without the spaces around it (None: none given)."""
    names = tuple(dict.fromkeys(n.strip() for n in (text or "").split(",") if n.strip()))
    return names or None


def _study_help() -> str:
    """The study names from the registry, each with the part of the paper it reproduces."""
    return "; ".join(f"{s.name} ({s.paper})" for s in STUDIES.values()) + "."


@friendly
def study(
    name: Annotated[StudyChoice, typer.Argument(help=_study_help())],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Results folder (table.md, results.json, plot.png; parts/ to resume).")
    ],
    budget: Annotated[
        BudgetChoice, typer.Option("--budget", help="cpu (fits a small CPU machine) or full (the paper's scale).")
    ] = BudgetChoice(get_args(Budget)[0]),
    model: Annotated[
        Path | None, typer.Option("--model", help="A 5-frame checkpoint for the KT3DMoSeg clips (default: shipped).")
    ] = None,
    pair_model: Annotated[
        Path | None,
        typer.Option("--pair-model", help="A two-view checkpoint for the AdelaideRMF pairs (default: shipped)."),
    ] = None,
    clips: Annotated[
        str | None,
        typer.Option("--clips", help="tsne: comma-separated KT3DMoSeg sequences / AdelaideRMF pairs."),
    ] = None,
    k_max: KMax = K_MAX,
    data_root: DataRoot = None,
    device: Device = None,
    threads: Annotated[int, typer.Option("--threads", min=1, help="CPU threads.")] = 1,
    verbose: Verbose = False,
) -> None:
    """Run a study of the paper: prints and writes a table, results.json and a plot; a re-run skips finished parts."""
    setup_run(threads, verbose)
    from mosegpipe.studies import StudyRequest, get_study

    chosen = get_study(enum_value(name))
    check_model_path(model)
    if pair_model is not None and not pair_model.is_file():
        raise InputError(f"{pair_model}: checkpoint file not found (--pair-model)")
    request = StudyRequest(
        out_dir=out,
        data_root=resolve_data_root(data_root) if chosen.needs_data else data_root,
        budget=enum_value(budget),
        model=model,
        pair_model=pair_model,
        clips=tuple(c.strip() for c in clips.split(",") if c.strip()) if clips else None,
        k_max=k_max,
        device=device,
        progress=typer.echo if verbose else None,
    )
    result = chosen.run(chosen, request)
    typer.echo(result.table)
    typer.echo(f"wrote {', '.join(str(p) for p in result.files)}")
