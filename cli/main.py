"""The `moseg` command: the Typer app with every command registered, in the order --help lists them.

The console script (`moseg = "mosegpipe.cli.main:app"`) runs `app`. Each command is thin (parse ->
one library call -> print): run / pair / tracks in clip.py, export in export.py, batch in batch.py, live in live.py,
replay / view in view.py, train / eval / study in evaluate.py. The error policy, `--version` and the
Typer app itself are app.py's; the options several commands share are defined once in options.py,
--config in config.py.
"""

from __future__ import annotations

from mosegpipe.cli.app import EXIT_CODES, MosegCommand, app
from mosegpipe.cli.batch import batch
from mosegpipe.cli.clip import pair, run, tracks
from mosegpipe.cli.evaluate import eval_, study, train
from mosegpipe.cli.export import export
from mosegpipe.cli.live import live
from mosegpipe.cli.view import replay, view

__all__ = ["EXIT_CODES", "app"]

if not app.registered_commands:  # once per process, also when this file runs as __main__ beside an import
    for command in (run, pair, tracks, export, batch, live, replay, view, train):
        app.command(cls=MosegCommand)(command)
    app.command("eval", cls=MosegCommand)(eval_)
    app.command(cls=MosegCommand)(study)

if __name__ == "__main__":
    app()
