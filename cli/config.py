"""--config FILE.toml: option values from a file, checked as the command line checks them (the command
line wins). Keys are option names without '--'; a [run] / [pair] / [batch] / [tracks] table applies to
that command only (docs/CLI.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, get_args

import typer

from mosegpipe.cli.app import app, bad_value, click_api, one_line

CONFIG_COMMANDS = ("run", "pair", "batch", "tracks")
"""The commands that take --config (a [table] named after one of them applies to that command only)."""


class _ConfigError(click_api.exceptions.ClickException):
    """A bad config file: one 'moseg: error:' line and exit code 1 (not a usage error)."""

    exit_code = 1


def _option_hints(command: str) -> dict[str, Any]:
    """The Python type of each parameter of a command (Annotated and Optional stripped)."""
    import types
    import typing

    fn = next(c.callback for c in app.registered_commands if (c.name or getattr(c.callback, "__name__", "")) == command)
    hints = {}
    for name, hint in typing.get_type_hints(fn).items():
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)
        hints[name] = next(a for a in get_args(hint) if a is not type(None)) if union else hint
    return hints


def _toml_value(value: Any, kind: Any, where: str, folder: Path) -> Any:
    """A value from the file checked against the option's type (TOML types, no coercion from strings)."""
    expected = {bool: "true or false", int: "an integer", float: "a number"}.get(kind, "a string")
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    else:
        ok = isinstance(value, str)
    if not ok:
        raise _ConfigError(f"{where}: expected {expected}, got {value!r}")
    if kind is Path:
        path = Path(value).expanduser()
        return str(path if path.is_absolute() else (folder / path).resolve())  # relative to the file, not the shell
    return value


def _options_of(command: Any) -> dict[str, Any]:
    """A command's options by name without '--' (`k-method`), --config and --help left out."""
    return {
        opt[2:]: param
        for param in command.params
        if param.name not in ("config", "help")
        for opt in param.opts
        if opt.startswith("--")
    }


def _other_commands_options(ctx: Any, command: str) -> set[str]:
    """The option names of the other commands that take --config (CONFIG_COMMANDS): a top-level key of theirs
    is not an error for this one."""
    group = ctx.parent.command if ctx.parent is not None else None
    if group is None or not hasattr(group, "get_command"):
        return set()
    names: set[str] = set()
    for other in CONFIG_COMMANDS:
        cmd = group.get_command(ctx.parent, other) if other != command else None
        names |= set(_options_of(cmd)) if cmd is not None else set()
    return names


def _config_defaults(path: Path, ctx: Any) -> dict[str, Any]:
    """Option values from a TOML file, checked as the command line would check them, keyed by parameter name."""
    import tomllib

    command = ctx.info_name or ""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise _ConfigError(f"{path}: no such config file (--config)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _ConfigError(f"{path}: cannot read the config file ({getattr(exc, 'strerror', None) or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise _ConfigError(f"{path}: not valid TOML ({one_line(str(exc))})") from None
    options = _options_of(ctx.command)
    elsewhere = _other_commands_options(ctx, command)
    for key, value in data.items():
        if isinstance(value, dict) and key not in CONFIG_COMMANDS:
            raise _ConfigError(f"{path}: unknown table [{key}] (tables: {', '.join(CONFIG_COMMANDS)})")
    # The top level first, then this command's table: its values win.
    values = {key: value for key, value in data.items() if not isinstance(value, dict)}
    table = data.get(command)
    values |= {f"{command}.{key}": value for key, value in table.items()} if isinstance(table, dict) else {}
    hints = _option_hints(command)
    defaults: dict[str, Any] = {}
    spelled: dict[tuple[str, str], str] = {}  # (table, option) -> the key that set it
    for key, value in values.items():
        table_name, _, name = key.rpartition(".")
        param = options.get(name.replace("_", "-"))
        if param is not None and (table_name, name.replace("_", "-")) in spelled:
            # 'k-method' and 'k_method' in one table: which one is meant is a guess, so neither is taken.
            first = spelled[(table_name, name.replace("_", "-"))]
            raise _ConfigError(f"{path}: {first!r} and {key!r} set the same option; keep one of them")
        spelled[(table_name, name.replace("_", "-"))] = key
        if param is None and not table_name and name.replace("_", "-") in elsewhere:
            continue  # a top-level key for the other commands that read the file (docs/CLI.md)
        if param is None:
            import difflib

            close = difflib.get_close_matches(name.replace("_", "-"), list(options), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f" (options: {', '.join(sorted(options))})"
            raise _ConfigError(f"{path}: unknown key {key!r} for 'moseg {command}'{hint}")
        where = f"{path}: {key}"
        raw = _toml_value(value, hints.get(param.name, str), where, path.parent)
        try:
            param.process_value(ctx, raw)
        except click_api.exceptions.BadParameter as exc:
            raise _ConfigError(f"{where} = {value!r}: {bad_value(exc)}") from None
        defaults[param.name] = raw
    return defaults


def _load_config(ctx: typer.Context, param: typer.CallbackParam, value: Path | None) -> Path | None:
    """--config callback (eager: it runs before the other options pick their defaults)."""
    if value is not None and not ctx.resilient_parsing:
        ctx.default_map = {**(ctx.default_map or {}), **_config_defaults(value, ctx)}
    return value


ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        is_eager=True,
        callback=_load_config,
        help="A TOML file of option values (keys: option names without '--', e.g. frames = 5, k-method = 'residual'; "
        "a [run] / [pair] / [batch] / [tracks] table applies to that command only). Options on the command line win. "
        "See docs/CLI.md.",
    ),
]
