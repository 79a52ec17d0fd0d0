"""Named training recipes and the data sources they draw from.

A source is a name ("synthetic", "kt3d", "hopkins", "adelaide", ...) turned into clips by its entry in
`SOURCES` and into a sampler by `build_sampler`; a recipe is a weighted mix of sources plus model and
training hyper-parameters and the recipe it starts from. Training itself is `run.train_recipe` /
`run.train_sources`.
Held-out sequences are excluded by name, so leave-one-out folds never see their test sequence.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from mosegpipe.embed.model import ModelConfig
from mosegpipe.errors import ConfigError, lookup
from mosegpipe.points.trajectories import window_starts
from mosegpipe.training.augment import PAIR_AUGMENT, TRACK_AUGMENT, TrackAugmentConfig, augment_point_set
from mosegpipe.training.loop import Sampler, TrainConfig, clip_sampler, mixture_sampler
from mosegpipe.types import LabeledClip


@dataclass(frozen=True)
class Recipe:
    """A named training recipe.

    Attributes:
        name: the preset name given to `moseg train --preset`.
        description: one line for `moseg train --help` and the model card.
        train: training hyper-parameters.
        model: architecture.
        sources: (source name, weight) pairs mixed by weight.
        init: the recipe whose checkpoint training starts from (None = from scratch); see
            run.train_recipe.
    """

    name: str
    description: str
    train: TrainConfig
    model: ModelConfig
    sources: tuple[tuple[str, float], ...]
    init: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The recipe as plain data (for the model card and checkpoints)."""
        return {
            "name": self.name,
            "description": self.description,
            "sources": [list(s) for s in self.sources],
            "init": self.init,
        }


# 12 blocks rather than the paper's 30-50: on this 2-core CPU a 12-block step costs ~40 % of a
# 30-block one, and within a fixed training time more steps beat more depth (docs/RESULTS.md).
# "motion" input normalisation: see model.ModelConfig.
_F5 = ModelConfig(in_dim=10, width=64, num_blocks=12, embed_dim=5, input_norm="motion")
_F2 = ModelConfig(in_dim=4, width=64, num_blocks=30, embed_dim=5)

RECIPES: dict[str, Recipe] = {
    r.name: r
    for r in (
        Recipe(
            "clip-f5",
            "shipped 5-frame model: fine-tunes base-f5 on our own KLT tracks of the KT3DMoSeg frames "
            "(augmented), Hopkins155 windows and synthetic clips",
            # Our own tracks rather than the benchmark's trajectories: measured on a two-fold split of
            # KT3DMoSeg (11 sequences held out, 600 steps, scored end to end as kt3d-video): 24.7 % error
            # trained on the benchmark's trajectories, 18.0 % on our tracks, 14.6 % on our tracks with
            # point-set augmentation; 12.9 % with 1500 steps (docs/RESULTS.md). Up to 1000 points per
            # clip: KLT gives up to 1000 tracks and the context statistics depend on the density.
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (("kt3d-own", 0.5), ("hopkins", 0.25), ("synthetic", 0.25)),
            init="base-f5",
        ),
        Recipe(
            "clip-f5-rendered",
            "clip-f5 with our own KLT tracks of photo-textured rendered clips added (an experiment, not shipped)",
            # kt3d-video leave-one-out at 1500 steps: 15.96 % against 15.59 % (500 steps) for clip-f5; on the
            # development split 7.60 % against 8.19 %, within the spread between training runs (docs/RESULTS.md).
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (("kt3d-own", 0.3), ("rendered-own", 0.4), ("hopkins", 0.15), ("synthetic", 0.15)),
            init="base-f5",
        ),
        Recipe(
            "clip-f5-davis",
            "clip-f5 with our own KLT tracks of the DAVIS-2016 train clips of the development part added "
            "(an experiment, not shipped)",
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (("kt3d-own", 0.4), ("davis-dev-own", 0.2), ("hopkins", 0.2), ("synthetic", 0.2)),
            init="base-f5",
        ),
        Recipe(
            "clip-f5-variety",
            "clip-f5 with our own KLT tracks of composites of the DAVIS development clips (several objects "
            "moving independently over real video) and of photo-textured rendered clips added (an experiment, "
            "not shipped)",
            # Dev, against clip-f5 retrained from the same base-f5, mean of two training seeds: composites
            # J 0.267 -> 0.284, composite-clip5 0.306 -> 0.327, rendered 0.702 both, kt3d-video 4.49 -> 5.79 %
            # (docs/results/41-diagnosis.md).
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (
                ("kt3d-own", 0.35),
                ("composite-own", 0.3),
                ("rendered-own", 0.1),
                ("hopkins", 0.1),
                ("synthetic", 0.15),
            ),
            init="base-f5",
        ),
        Recipe(
            "clip-f5-composites",
            "clip-f5 with a quarter of its clips from composite-own instead (KT3DMoSeg's share kept at a half, no "
            "rendered clips; an experiment, not shipped)",
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (("kt3d-own", 0.5), ("composite-own", 0.25), ("hopkins", 0.125), ("synthetic", 0.125)),
            init="base-f5",
        ),
        Recipe(
            "clip-f5-near",
            "clip-f5 with our own KLT tracks of rendered clips whose static world stands near a trucking camera "
            "(boxes 1.5-3 m away, the wall beyond; half of them following a mover) added, so that a static 3D "
            "scene stays one group (an experiment, not shipped)",
            TrainConfig(frames=5, steps=1500, batch_size=8, lr=1e-3, max_points=1000),
            _F5,
            (("kt3d-own", 0.4), ("rendered-near-own", 0.2), ("hopkins", 0.2), ("synthetic", 0.2)),
            init="base-f5",
        ),
        Recipe(
            "base-f5",
            "5-frame starting point without KT3DMoSeg: synthetic clips and Hopkins155 windows",
            # No time budget, so that the steps done (and the weights) do not depend on the machine's speed.
            TrainConfig(frames=5, steps=4000, batch_size=8, lr=1e-3),
            _F5,
            (("synthetic", 0.5), ("hopkins", 0.5)),
        ),
        Recipe(
            "synthetic-f5",
            "5-frame model from synthetic clips only (zero-shot on every benchmark)",
            TrainConfig(frames=5, steps=3000, batch_size=8, lr=1e-3),
            _F5,
            (("synthetic", 1.0),),
        ),
        Recipe(
            "pair-f2",
            "shipped two-view model: fine-tunes synthetic-f2 on synthetic pairs and our own SIFT matches of the "
            "AdelaideRMF images (augmented)",
            # Measured on a two-fold split of AdelaideRMF (10 pairs held out, scored end to end as
            # adelaide-pairs): 46.2 % error trained on the benchmark's correspondences (300 steps), 20.4 % on
            # our matches (300 steps), 9.2 % on our matches with 1000 steps (docs/RESULTS.md).
            TrainConfig(frames=2, steps=1000, batch_size=8, lr=1e-3, loss="l2"),
            _F2,
            (("synthetic-pair", 0.5), ("adelaide-own", 0.5)),
            init="synthetic-f2",
        ),
        Recipe(
            "synthetic-f2",
            "two-view model from synthetic pairs only (zero-shot on AdelaideRMF)",
            # "mimi-point": the worst-point MaxInterMinIntra that built the shipped two-view weights' starting
            # point (before "mimi" became the paper's sum-scatter form); kept so that pair-f2 rebuilds them.
            TrainConfig(frames=2, steps=2000, batch_size=8, lr=1e-3, loss="mimi-point"),
            _F2,
            (("synthetic-pair", 1.0),),
        ),
        Recipe(
            "lce",
            "the paper's synthetic lines/circles/ellipses benchmark (2-D points, F = 1)",
            TrainConfig(frames=1, steps=3000, batch_size=16, lr=1e-3, flip=True, reverse=False),
            ModelConfig(in_dim=2, width=64, num_blocks=30, embed_dim=5),
            (("lce", 1.0),),
        ),
    )
}


def get_recipe(name: str) -> Recipe:
    """The recipe called `name`.

    Raises:
        ConfigError: no recipe has that name; the message lists them.
    """
    return lookup(RECIPES, name, "recipe", sort=True)


def _windows(clip: LabeledClip, frames: int, stride: int) -> list[LabeledClip]:
    """Consecutive F-frame windows of a complete-trajectory clip."""
    out = []
    for start in window_starts(clip.num_frames, frames, "all", stride):
        traj = clip.traj[:, 2 * start : 2 * (start + frames)]
        out.append(
            replace(
                clip, name=f"{clip.name}/f{start + 1}-{start + frames}", traj=traj, meta={**clip.meta, "start": start}
            )
        )
    return out


def _synthetic(frames: int) -> Sampler:
    from mosegpipe.synth.trajectories import SyntheticConfig, generate_clip

    scfg = SyntheticConfig(frames=frames)

    def draw(rng: Any, _c: SyntheticConfig = scfg) -> LabeledClip:
        return generate_clip(rng, _c)

    return draw


def _synthetic_pair(frames: int) -> Sampler:
    from mosegpipe.synth.trajectories import PAIR_CONFIG, SyntheticConfig, generate_pair

    def draw(rng: Any, _c: SyntheticConfig = PAIR_CONFIG) -> LabeledClip:
        return generate_pair(rng, _c)

    return draw


def _kt3d(mode: str) -> Callable[[Path, int, Collection[str]], list[LabeledClip]]:
    def clips(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
        from mosegpipe.data.kt3dmoseg import kt3d_windows, list_kt3d_sequences, read_kt3d_sequence

        out: list[LabeledClip] = []
        for name in list_kt3d_sequences(data_root):
            if name in exclude:
                continue
            out.extend(kt3d_windows(read_kt3d_sequence(data_root, name), frames=frames, mode=mode))
        return [c for c in out if c.k >= 1]

    return clips


def _hopkins(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.data.hopkins155 import load_hopkins

    out: list[LabeledClip] = []
    for clip in load_hopkins(data_root):
        if clip.name in exclude:
            continue
        out.extend(_windows(clip, frames, stride=frames))
    return out


def _adelaide(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.data.adelaidermf import load_adelaide

    if frames != 2:
        raise ConfigError("the adelaide source is two-view: it needs frames = 2")
    return [c for c in load_adelaide(data_root) if c.name not in exclude]


def _kt3d_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import kt3d_own_clips

    return kt3d_own_clips(data_root, frames=frames, exclude=exclude)


def _rendered_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import rendered_own_clips

    return rendered_own_clips(data_root, frames, exclude=exclude)


def _rendered_near_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import RenderedTracksConfig, rendered_own_clips

    near = RenderedTracksConfig(num_clips=200, camera_motions=("truck",), near_static=(1, 4), follow_prob=0.5, seed=54)
    return rendered_own_clips(data_root, frames, exclude=exclude, cfg=near)


def _adelaide_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import adelaide_own_clips

    if frames != 2:
        raise ConfigError("the adelaide-own source is two-view: it needs frames = 2")
    return adelaide_own_clips(data_root, exclude=exclude)


def _davis_dev_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import davis_dev_own_clips

    return davis_dev_own_clips(data_root, frames=frames, exclude=exclude)


def _composite_own(data_root: Path, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.training.own_tracks import composite_own_clips

    return composite_own_clips(data_root, frames=frames, exclude=exclude)


def _augmented(sampler: Sampler, cfg: TrackAugmentConfig) -> Sampler:
    """`sampler` whose clips go through `augment_point_set` (a fresh draw of the augmentation each time)."""

    def draw(rng: Any) -> LabeledClip:
        clip = sampler(rng)
        traj, labels = augment_point_set(clip.traj, clip.labels, rng, cfg)
        return replace(clip, traj=traj, labels=labels)

    return draw


def _lce(data_root: Path | None, frames: int, exclude: Collection[str]) -> list[LabeledClip]:
    from mosegpipe.synth.lce import lce_splits

    return list(lce_splits()["train"])


@dataclass(frozen=True)
class Source:
    """One training source: labelled clips read from a benchmark, or clips generated on the fly.

    Attributes:
        name: the name recipes and `--exclude` use.
        description: one line for the model card and error messages.
        generate: generated sources: frames -> sampler drawing a fresh clip per call.
        clips: read sources: (data_root, frames, excluded names) -> the clips, loaded once.
        needs_data: whether `clips` reads the benchmark folder.
        augment: read sources: point-set augmentation applied to every drawn clip (see
            training/augment.py), for sources made by our own front end; None = none.
    """

    name: str
    description: str
    generate: Callable[[int], Sampler] | None = None
    clips: Callable[[Any, int, Collection[str]], list[LabeledClip]] | None = None
    needs_data: bool = True
    augment: TrackAugmentConfig | None = None


SOURCES: dict[str, Source] = {
    s.name: s
    for s in (
        Source(
            "synthetic",
            "multi-body perspective clips generated on the fly (synth/trajectories.py)",
            generate=_synthetic,
            needs_data=False,
        ),
        Source(
            "synthetic-pair",
            "two-view synthetic scenes with gross outliers as their own group",
            generate=_synthetic_pair,
            needs_data=False,
        ),
        Source("kt3d", "every F-frame window of the KT3DMoSeg sequences (fully visible tracks)", clips=_kt3d("all")),
        Source(
            "kt3d-first",
            "the frames 1..F clip of each KT3DMoSeg sequence (the paper's 'vanilla' training set)",
            clips=_kt3d("first"),
        ),
        Source("hopkins", "every F-frame window (stride F) of the Hopkins155 sequences", clips=_hopkins),
        Source("adelaide", "the AdelaideRMF two-view pairs, outliers as one more group", clips=_adelaide),
        Source(
            "kt3d-own",
            "our KLT tracks of every F-frame window of the KT3DMoSeg frames, labels by motion agreement",
            clips=_kt3d_own,
            augment=TRACK_AUGMENT,
        ),
        Source(
            "rendered-own",
            "our KLT tracks of rendered clips textured with real photographs (AdelaideRMF images, OpenCV "
            "samples; never KT3DMoSeg frames), labels from the rendered masks",
            clips=_rendered_own,
            augment=TRACK_AUGMENT,
        ),
        Source(
            "rendered-near-own",
            "rendered-own's clips under a camera trucking sideways past 1-4 still boxes 1.5-3 m away (the static "
            "world, label 0), half of them following the first mover; seed 54, 200 clips",
            clips=_rendered_near_own,
            augment=TRACK_AUGMENT,
        ),
        Source(
            "adelaide-own",
            "our SIFT matches of the AdelaideRMF image pairs, labels by motion agreement",
            clips=_adelaide_own,
            augment=PAIR_AUGMENT,
        ),
        Source(
            "davis-dev-own",
            "our KLT tracks of the DAVIS-2016 train clips of the development part (never the validation "
            "part), labels from the human masks: the main object against the rest",
            clips=_davis_dev_own,
            augment=TRACK_AUGMENT,
        ),
        Source(
            "composite-own",
            "our KLT tracks of every F-frame window of 40 composites (25 frames, 427x240, 2-4 objects) of the "
            "DAVIS-2016 train clips of the development part (never the validation part), seeds 1041 (not the "
            "scored composites' 41), labels from the exact per-object masks (an object still in the world "
            "is the world)",
            clips=_composite_own,
            augment=TRACK_AUGMENT,
        ),
        Source("lce", "the synthetic lines/circles/ellipses training split", clips=_lce, needs_data=False),
    )
}
"""Every training source by name; a new source is one more entry."""


def get_source(name: str) -> Source:
    """The training source called `name`.

    Raises:
        ConfigError: no source has that name; the message lists them.
    """
    return lookup(SOURCES, name, "source", sort=True)


def source_clips(source: str, data_root: Path | None, frames: int, exclude: Collection[str] = ()) -> list[LabeledClip]:
    """The labelled clips of a read (not generated) source, without the sequences named in `exclude`.

    Args:
        source: the name of a source with `clips` ("kt3d", "kt3d-first", "hopkins", "adelaide", "lce").
        data_root: the benchmark folder (holding kt3dmoseg/, hopkins155/, adelaidermf/).
        frames: F of the clips to produce.
        exclude: sequence / pair names to leave out (held-out folds).

    Raises:
        ConfigError: unknown or generated source, or no data root for a source that needs one.
    """
    src = get_source(source)
    if src.clips is None:
        raise ConfigError(f"unknown source {source!r}; choose from {', '.join(sorted(SOURCES))}")
    if src.needs_data and data_root is None:
        raise ConfigError(f"source {source!r} needs a data root")
    return src.clips(data_root, frames, exclude)


def build_sampler(
    sources: Sequence[tuple[str, float]],
    data_root: Path | None,
    frames: int,
    exclude: Collection[str] = (),
    seed: int = 0,
) -> tuple[Sampler, dict[str, Any]]:
    """A mixture sampler over `sources`, plus a plain-data description of what it holds.

    Generated sources draw clips on the fly; read sources are loaded once.

    Raises:
        ConfigError: an unknown source, one without its data, one that gives no clips, or no
            source with a positive weight.
    """
    parts: list[tuple[float, Sampler]] = []
    described: dict[str, Any] = {}
    for name, weight in sources:
        if weight <= 0:
            continue
        src = get_source(name)
        if src.generate is not None:
            parts.append((weight, src.generate(frames)))
            described[name] = {"weight": weight, "generated": True}
        else:
            clips = source_clips(name, data_root, frames, exclude)
            if not clips:
                raise ConfigError(f"source {name!r} gave no clips (frames={frames}, excluded {sorted(exclude)})")
            sampler = clip_sampler(clips)
            parts.append((weight, sampler if src.augment is None else _augmented(sampler, src.augment)))
            described[name] = {"weight": weight, "num_clips": len(clips), "excluded": sorted(exclude)}
            if src.augment is not None:
                described[name]["augment"] = asdict(src.augment)
    if not parts:
        raise ConfigError("no training source with a positive weight")
    return mixture_sampler(parts), described
