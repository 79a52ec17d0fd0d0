"""moseg export: an output folder's masks as per-object binary PNGs, alpha mattes, a cut-out video, DAVIS
palette PNGs or an npz (mosegpipe.apps.export); parse the options, one library call, print."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, TypeAlias

import typer

from mosegpipe.cli.app import friendly, setup_run
from mosegpipe.cli.common import print_total
from mosegpipe.cli.options import Verbose, choice_type
from mosegpipe.types import EXPORT_FORMATS

if TYPE_CHECKING:
    from enum import StrEnum

    ExportAs: TypeAlias = StrEnum
else:
    ExportAs = choice_type("ExportAs", EXPORT_FORMATS)  # --as


@friendly
def export(
    out: Annotated[Path, typer.Argument(help="An output folder of moseg run, pair, tracks --video or live --out.")],
    as_: Annotated[
        ExportAs,
        typer.Option(
            "--as",
            help="binary: masks_by_object/OBJECT/NNNNNN.png (0/255); alpha: alpha/NNNNNN.png (RGBA, the frame with "
            "the objects opaque); cutout: cutout.mov (the objects on transparency, PNG in QuickTime) or, with "
            "--background, cutout.mp4 (H.264); davis: davis/NNNNN.png (DAVIS palette, objects 1..n); npz: masks.npz.",
        ),
    ],
    objects: Annotated[
        str | None,
        typer.Option("--objects", help="Comma-separated mask values to export, e.g. 1,3 (default: every moving one)."),
    ] = None,
    to: Annotated[
        Path | None, typer.Option("--to", help="Folder to write into (default: the output folder itself).")
    ] = None,
    background: Annotated[
        str | None,
        typer.Option("--background", help="--as cutout: an H.264 cutout.mp4 on this colour, #RRGGBB or R,G,B."),
    ] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an earlier export of the same form.")] = False,
    verbose: Verbose = False,
) -> None:
    """Write the masks of an earlier run in another form, without running it again (docs/OUTPUTS.md, "Exports").

    Objects are mask values: 1, 2, ... the moving motions, 254 moving without a clustered motion (0, the
    world, is no object). alpha and cutout read the source frames again (they must be unchanged).
    """
    started = time.perf_counter()
    setup_run(1, verbose)
    from mosegpipe.apps.export import export_masks, parse_colour, parse_objects

    chosen = parse_objects(objects) if objects is not None else None
    colour = parse_colour(background) if background is not None else None
    done = export_masks(out, str(as_.value), chosen, to=to, background=colour, overwrite=overwrite)
    listed = ", ".join(map(str, done.objects)) or "none"
    typer.echo(f"wrote {done.path} ({done.frames} frames; objects {listed})")
    print_total(started)
