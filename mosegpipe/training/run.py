"""The one training entry point: `moseg train --preset NAME` and every leave-one-out fold train through here.

`train_sources` turns a weighted mix of sources into a sampler and trains one model; `train_recipe`
trains a named recipe exactly as it is written down, starting from its `init` recipe's checkpoint
(trained first when it is not there yet), and saves a self-describing checkpoint.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mosegpipe.embed.model import ModelConfig, SubspaceNet
from mosegpipe.training.loop import TrainConfig, TrainResult, recipe_of, train_model, with_overrides
from mosegpipe.training.recipes import Recipe, build_sampler, get_recipe, get_source

log = logging.getLogger(__name__)


def train_sources(
    sources: Sequence[tuple[str, float]],
    data_root: Path | None,
    cfg: TrainConfig,
    model_cfg: ModelConfig | None = None,
    init: SubspaceNet | None = None,
    exclude: Collection[str] = (),
    on_start: Callable[[dict[str, Any]], None] | None = None,
    on_log: Callable[[dict[str, float]], None] | None = None,
    device: str = "cpu",
) -> tuple[TrainResult, dict[str, Any]]:
    """Trains one model on a weighted mix of training sources.

    Args:
        sources: (source name, weight) pairs; names from recipes.SOURCES.
        data_root: the benchmark folder (None when every source is generated).
        cfg: training hyper-parameters (cfg.frames is the trajectory length F).
        model_cfg: architecture of a model trained from scratch (ignored with `init`).
        init: start from this model (fine-tuning) instead of a fresh one.
        exclude: sequence / clip names left out of every source (the held-out fold).
        on_start: called with the description of the sources before the first step.
        on_log: called with each logged step (step, loss, lr, seconds).
        device: where the model trains (a checked name, see loop.resolve_device; the model stays there).

    Returns:
        The training result and the plain-data recipe (settings, sources, seconds, steps) to store
        in the checkpoint.

    Raises:
        ConfigError: an unknown source, a source without the data it needs, or no clips at all.
    """
    sampler, described = build_sampler(sources, data_root, cfg.frames, exclude=exclude, seed=cfg.seed)
    if on_start is not None:
        on_start(described)
    result = train_model(sampler, cfg, model_cfg=model_cfg, init=init, on_log=on_log, device=device)
    return result, recipe_of(cfg, described, result)


@dataclass(frozen=True)
class TrainOverrides:
    """Settings given on the command line instead of the recipe's (None = the recipe's value).

    Attributes:
        steps, batch_size, lr, loss, seed, time_budget_s: TrainConfig fields.
    """

    steps: int | None = None
    batch_size: int | None = None
    lr: float | None = None
    loss: str | None = None
    seed: int | None = None
    time_budget_s: float | None = None

    def apply(self, cfg: TrainConfig) -> TrainConfig:
        """`cfg` with the given fields replaced."""
        return with_overrides(
            cfg,
            steps=self.steps,
            batch_size=self.batch_size,
            lr=self.lr,
            loss=self.loss,
            seed=self.seed,
            time_budget_s=self.time_budget_s,
        )


def recipe_sources(recipe: Recipe, exclude_sources: Collection[str] = ()) -> tuple[tuple[str, float], ...]:
    """The recipe's (source, weight) pairs without the excluded source names (leave-one-dataset-out)."""
    return tuple((s, w) for s, w in recipe.sources if s not in set(exclude_sources))


def needs_data(name: str, exclude_sources: Collection[str] = ()) -> bool:
    """Whether training recipe `name` (or a recipe it starts from) reads benchmark data."""
    recipe = get_recipe(name)
    if any(get_source(s).needs_data for s, _ in recipe_sources(recipe, exclude_sources)):
        return True
    return recipe.init is not None and needs_data(recipe.init)


def train_recipe(
    name: str,
    out: Path,
    data_root: Path | None = None,
    init: Path | None = None,
    overrides: TrainOverrides = TrainOverrides(),
    exclude_sources: Collection[str] = (),
    command: str = "",
    on_start: Callable[[Recipe, TrainConfig, dict[str, Any]], None] | None = None,
    on_log: Callable[[dict[str, float]], None] | None = None,
    device: str = "cpu",
) -> TrainResult:
    """Trains recipe `name` and writes its checkpoint to `out`.

    Without `init` the recipe's own `init` recipe is the starting point: its checkpoint
    `out.parent / "<init>.pt"` is used when it exists (and was made by that recipe), and is trained
    first, exactly as its recipe says, when it does not. So `train_recipe("clip-f5", ...)` with no
    overrides rebuilds the shipped 5-frame model the way weights/MODEL_CARD.md describes.

    Args:
        name: a recipe in recipes.RECIPES.
        out: checkpoint file to write.
        data_root: the benchmark folder (None when every source is generated).
        init: fine-tune from this checkpoint instead of the recipe's init.
        overrides: settings replacing the recipe's (this recipe only, never its init).
        exclude_sources: source names left out (leave-one-dataset-out).
        command: the command line, recorded in the checkpoint.
        on_start: called with (recipe, settings, sources) before each training run starts.
        on_log: called with each logged step.
        device: where it trains, its init recipe too ("cpu", "cuda", "cuda:N"; see loop.resolve_device).

    Returns:
        The training result; its model was saved to `out`.

    Raises:
        ConfigError: unknown recipe or source, or a source without its data.
        CheckpointError: `init` is missing or not a SubspaceNet checkpoint.
    """
    recipe = get_recipe(name)
    start: SubspaceNet | None = None
    init_label: str | None = str(init) if init else None
    if init is not None:
        start = SubspaceNet.from_checkpoint(init)
    elif recipe.init is not None:
        init_path = Path(out).parent / f"{recipe.init}.pt"
        if init_path.is_file() and SubspaceNet.from_checkpoint(init_path).recipe.get("name") == recipe.init:
            log.info("%s: starting from %s (already trained)", name, init_path)
        else:
            train_recipe(
                recipe.init, init_path, data_root, command=command, on_start=on_start, on_log=on_log, device=device
            )
        start = SubspaceNet.from_checkpoint(init_path)
        init_label = str(init_path)
    cfg = overrides.apply(recipe.train)
    result, rec = train_sources(
        recipe_sources(recipe, exclude_sources),
        data_root,
        cfg,
        model_cfg=recipe.model,
        init=start,
        on_start=None if on_start is None else (lambda described: on_start(recipe, cfg, described)),
        on_log=on_log,
        device=device,
    )
    rec.update(name=name, command=command, init=init_label, excluded=sorted(set(exclude_sources)))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    result.model.save(out, recipe=rec)
    return result
