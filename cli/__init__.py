"""The moseg command-line interface (installed as mosegpipe.cli)."""
