"""What the studies share: the Study record and its request / result, the --budget check, resumable
parts (`OUT/parts/`, keyed by a hash of what a part depends on), model identity, the test clips and
the figure and results writers.

registry.py and the study modules it registers (imbalance, lce, training) all import from here, never
from each other. Nothing heavy is imported at import time.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast, get_args

from mosegpipe.errors import ConfigError, check_choice

if TYPE_CHECKING:
    from mosegpipe.embed.model import SubspaceNet
    from mosegpipe.types import LabeledClip

Budget = Literal["cpu", "full"]
"""--budget: "cpu" fits a small CPU machine; "full" is the paper's scale."""

# Bumped when a study's computation changes, so that stored parts of the old code are redone.
PARTS_VERSION = 1


@dataclass(frozen=True)
class StudyRequest:
    """What one `moseg study` run asks of a study (each study uses the settings that apply to it).

    Attributes:
        out_dir: results folder (table.md, results.json, plot.png; parts/ to resume).
        data_root: the benchmark folder.
        budget: "cpu" or "full".
        model: a 5-frame checkpoint instead of the shipped one (KT3DMoSeg clips).
        pair_model: a two-view checkpoint instead of the shipped one (AdelaideRMF pairs).
        clips: tsne: the clips to show (KT3DMoSeg sequence or AdelaideRMF pair names; None = defaults).
        k_max: largest K considered by every automatic-K rule.
        device: where training studies train ("cpu", "cuda", "cuda:N" or "auto"; see
            training.loop.resolve_device); None: cpu, except lce-curve --budget full (cuda when there is one).
        progress: called with one line per finished part.
    """

    out_dir: Path
    data_root: Path | None = None
    budget: str = "cpu"
    model: Path | None = None
    pair_model: Path | None = None
    clips: tuple[str, ...] | None = None
    k_max: int = 8
    device: str | None = None
    progress: Callable[[str], None] | None = field(default=None, compare=False)


@dataclass(frozen=True)
class StudyResult:
    """What a study produced (also written to out_dir).

    Attributes:
        table: the Markdown written to table.md (and printed by the CLI).
        results: what results.json holds.
        files: the files written.
    """

    table: str
    results: dict[str, Any]
    files: list[Path]


@dataclass(frozen=True)
class Study:
    """One study of the paper.

    Attributes:
        name: what `moseg study NAME` is called with.
        description: one line for --help and the README.
        paper: the table or figure of the paper it reproduces.
        run: (study, request) -> StudyResult; writes the files.
        needs_data: whether it reads the benchmark folder.
        budgets: "cpu" / "full" -> what the budget means for this study.
    """

    name: str
    description: str
    paper: str
    run: Callable[[Study, StudyRequest], StudyResult]
    needs_data: bool = True
    budgets: dict[str, str] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# Shared helpers: resumable parts, model identity, clips, plots


def stable_hash(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def model_id(model: SubspaceNet) -> str:
    """A short hash of a model's weights: parts computed with other weights are redone."""
    digest = hashlib.sha256()
    for name, tensor in sorted(model.state_dict().items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


def part_path(req: StudyRequest, key: str, suffix: str) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in key)
    return req.out_dir / "parts" / f"{safe}{suffix}"


def load_part(path: Path, config_hash: str) -> dict[str, Any] | None:
    """A stored part's payload if it was computed under `config_hash`, else None."""
    if not path.is_file():
        return None
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if stored.get("config_hash") != config_hash:
        return None
    return cast(dict[str, Any], stored["payload"])


def save_part(path: Path, config_hash: str, payload: dict[str, Any]) -> None:
    from mosegpipe.io.read import write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, {"config_hash": config_hash, "payload": payload})


def check_budget(req: StudyRequest) -> Budget:
    return cast(Budget, check_choice("--budget", req.budget, get_args(Budget)))


def budget_note(study: Study, budget: str) -> str:
    same = len(set(study.budgets.values())) == 1
    what = study.budgets.get(budget, "")
    return f"Budget: {budget} ({what}{'; --budget cpu and full are the same for this study' if same else ''})."


def resolve_data_root(req: StudyRequest, study: Study) -> Path:
    if req.data_root is None:
        raise ConfigError(f"study {study.name} needs the benchmark data (--data-root or MOSEG_DATA)")
    return req.data_root


def study_models(req: StudyRequest) -> tuple[SubspaceNet, SubspaceNet]:
    """(5-frame model, two-view model): the request's checkpoints or the shipped weights."""
    from mosegpipe.embed.numpy_net import load_model

    return load_model(5, req.model), load_model(2, req.pair_model)


def load_datasets(root: Path) -> dict[str, list[LabeledClip]]:
    """The test clips the studies read: KT3DMoSeg frames 1-5 of every sequence, every AdelaideRMF pair."""
    from mosegpipe.data.adelaidermf import load_adelaide
    from mosegpipe.data.kt3dmoseg import kt3d_test_clips

    return {"kt3dmoseg": kt3d_test_clips(root, frames=5), "adelaidermf": load_adelaide(root)}


DATASET_TITLES = {"kt3dmoseg": "KT3DMoSeg", "adelaidermf": "AdelaideRMF"}


def pyplot_module() -> Any:
    """matplotlib's pyplot on the Agg backend (files only, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig: Any, path: Path, dpi: int = 80) -> None:
    from mosegpipe.io.read import atomic_write

    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    pyplot_module().close(fig)


def write_outputs(req: StudyRequest, table: str, results: dict[str, Any], fig: Any) -> list[Path]:
    from mosegpipe.io.read import write_json, write_text

    req.out_dir.mkdir(parents=True, exist_ok=True)
    paths = [req.out_dir / "table.md", req.out_dir / "results.json", req.out_dir / "plot.png"]
    write_text(paths[0], table)
    write_json(paths[1], results)
    _save_figure(fig, paths[2])
    return paths
