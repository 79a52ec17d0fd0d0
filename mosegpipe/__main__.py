"""`python -m mosegpipe ...`: the `moseg` command (mosegpipe.cli.main), for environments without the
console script on PATH."""

from __future__ import annotations

from mosegpipe.cli.main import app

if __name__ == "__main__":
    app(prog_name="moseg")
