"""The Typer app and the error policy of every moseg command, in one place.

Only the CLI prints, and only here does a MosegError (or an OS error, Ctrl-C, SIGTERM) become one
line on stderr and exit code 1, 130 or 143 (`friendly`, `exit_with_error`); usage errors are one line with exit code 2
(`_MosegGroup`). `setup_run` sets logging, native log levels and threads before a command imports the
library; `--version` is the app's callback. The commands live in the modules beside this one and are
registered, in the order --help lists them, by cli/main.py.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import logging
import os
import re
import shutil
import signal
import sys
import textwrap
from collections.abc import Callable, Iterator
from typing import Annotated, Any, TypeVar

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from mosegpipe import __version__
from mosegpipe.errors import MosegError

try:  # Typer >= 0.26 bundles its own copy of Click; its exceptions are the ones raised
    from typer import _click as click_api
except ImportError:  # pragma: no cover - older Typer uses the click package
    import click as click_api  # type: ignore[no-redef]


EXIT_CODES = {
    0: "success (also when stdout was closed early, as by `| head`)",
    1: "bad input or a failed run (one 'moseg: error:' line)",
    2: "usage error",
    129: "terminated by SIGHUP, its terminal closed (one 'moseg: error: terminated (SIGHUP)' line)",
    130: "interrupted by Ctrl-C (one 'moseg: error: interrupted' line)",
    143: "terminated by SIGTERM (one 'moseg: error: terminated (SIGTERM)' line)",
}
"""Exit codes of every moseg command (docs/CLI.md): 128 + the signal for a signal, as shells do."""

INTERRUPTED = 130
TERMINATED = 143
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)  # no SIGHUP on Windows


def _stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader went away (`moseg ... | head -1`): its write end
    reports an error to poll(). Where poll() is missing, any broken pipe is taken for stdout."""
    import select

    if not hasattr(select, "poll"):
        return True
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(event & select.POLLERR for _, event in poller.poll(0))
    except (OSError, ValueError):  # no real file behind sys.stdout (tests, a closed stream)
        return False


def _silence_stdout() -> None:
    """Points stdout at /dev/null, so that the flush at exit does not fail again (Python's docs on
    SIGPIPE advise this)."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


class _Argument(TyperArgument):
    """An argument named in capitals in the usage line (`CLIP`, `[NAME]` when optional), as Click and
    argparse write them, not Typer's `{clip}`; a long list of choices the help text names itself
    shows as `<name>` in the type column (the list wrapped into a narrow column otherwise)."""

    def _usage_display_name(self) -> str:
        name = self.display_name_raw.upper()
        name = name if self.required else f"[{name}]"
        return name + ("..." if self.nargs != 1 else "")

    def display_type_rich(self, ctx: Any) -> str | None:
        shown = self.display_type(ctx)
        return "<name>" if _named_in_help(self, shown) else shown


class _Option(TyperOption):
    """An option without the `<bool>` of a flag; its choices stay listed (`--help` is where they are
    read), in the type column, or as `<name>` there when the list is long and the help text names
    every choice itself (as `_Argument`)."""

    def display_type_rich(self, ctx: Any) -> str | None:
        if self.is_flag and self.metavar is None:
            return None
        shown = super().display_type_rich(ctx)
        return "<name>" if shown is not None and _named_in_help(self, shown) else shown


def _named_in_help(param: Any, shown: str) -> bool:
    choices = shown.strip("<>").split("|")
    help_text = param.help or ""
    return len(shown) > 24 and len(choices) > 1 and all(c in help_text for c in choices)


NARROW_HELP_COLUMNS = 100
"""Below this terminal width `--help` takes the plain layout (MosegCommand.format_help)."""


class MosegCommand(TyperCommand):
    """A moseg command: its parameters shown as in `_Argument` and `_Option` (every command is
    registered with it, in cli/main.py)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            _reclass(param)

    def get_help_option(self, ctx: Any) -> Any:
        return _reclass(super().get_help_option(ctx))

    def format_help(self, ctx: Any, formatter: Any) -> None:
        """Rich's boxed table below 100 columns squeezes every help text into a sliver (four columns
        share the width); there the plain layout (option, then its help on the rest of the line) reads
        better."""
        if shutil.get_terminal_size().columns < NARROW_HELP_COLUMNS:
            rich_mode, self.rich_markup_mode = self.rich_markup_mode, None
            plain = _PlainFormatter(width=formatter.width)
            try:
                super().format_help(ctx, plain)
            finally:
                self.rich_markup_mode = rich_mode
            formatter.write(plain.getvalue())
        else:
            super().format_help(ctx, formatter)


class _PlainFormatter(click_api.HelpFormatter):
    """Click's plain help layout, with help texts wrapped at spaces only: `hopkins-test`, not
    `hopkins-` / `test` (names are copied from help)."""

    def write_dl(self, rows: Any, col_max: int = 30, col_spacing: int = 2) -> None:
        rows = list(rows)
        first_col = (
            min(max((click_api.formatting.term_len(term) for term, _ in rows), default=0), col_max) + col_spacing
        )
        width = max(self.width - first_col - 2, 10)
        # A paragraph that starts with \b is kept as given (click's wrap_text), so the wrapping here stays.
        kept = [
            (term, "\b\n" + textwrap.fill(text, width, break_on_hyphens=False) if text else text) for term, text in rows
        ]
        super().write_dl(kept, col_max, col_spacing)


def _reclass(param: Any) -> Any:
    """Typer's own parameter classes -> ours (same attributes, other display)."""
    if type(param) is TyperArgument:
        param.__class__ = _Argument
    elif type(param) is TyperOption:
        param.__class__ = _Option
    return param


def one_line(text: str) -> str:
    return " ".join(str(text).split())


def bad_value(exc: Any) -> str:
    """The reason in a BadParameter, one line, without the validator's "Value error, " prefix."""
    return one_line(exc.message).removeprefix("Value error, ").rstrip(".")


def _usage_message(exc: Any, args: list[str]) -> str:
    """One line for a usage error; a bad option value is named with the value given (`--frames 0: ...`)."""
    param = getattr(exc, "param", None)
    if isinstance(exc, click_api.exceptions.BadParameter) and param is not None and getattr(param, "opts", None):
        for i, arg in enumerate(args):
            for opt in param.opts:
                if arg == opt and i + 1 < len(args):
                    return f"{opt} {args[i + 1]}: {bad_value(exc)}"
                if arg.startswith(f"{opt}="):
                    return f"{opt} {arg[len(opt) + 1 :]}: {bad_value(exc)}"
        missing = isinstance(exc, click_api.exceptions.MissingParameter)
        if not missing and not any(opt.startswith("-") for opt in param.opts):  # PROTOCOL: 'x' is not one of ...
            return f"{param.name.upper()}: {bad_value(exc)}"
    return one_line(exc.format_message()).replace(": Value error, ", ": ").rstrip(".")


class _MosegGroup(TyperGroup):
    """The moseg command group: usage errors are one line on stderr, not Click's framed box.

    Click's own exit code 2 is kept for usage errors (a bad option value, a missing argument, an
    unknown option); everything a command reports itself exits with 1 (see EXIT_CODES). A stdout
    closed by its reader (`moseg ... | head -1`) ends the command quietly with 0, and Ctrl-C with
    130 and one line, wherever they happen (Click would print a blank line and exit 1).
    """

    def make_context(self, *args: Any, **kwargs: Any) -> Any:
        with _quiet_ends():
            return super().make_context(*args, **kwargs)

    def invoke(self, ctx: Any) -> Any:
        with _quiet_ends():
            return super().invoke(ctx)

    def main(
        self,
        args: Any = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        try:
            rv = super().main(
                args=args,
                prog_name=prog_name,
                complete_var=complete_var,
                standalone_mode=False,
                windows_expand_args=windows_expand_args,
                **extra,
            )
            code = rv if isinstance(rv, int) else 0
        except click_api.exceptions.NoArgsIsHelpError as exc:
            typer.echo(exc.ctx.get_help() if exc.ctx is not None else "")
            code = exc.exit_code
        except click_api.exceptions.UsageError as exc:
            where = exc.ctx.command_path if exc.ctx is not None else "moseg"
            message = _usage_message(exc, sys.argv[1:] if args is None else list(args))
            typer.echo(f"moseg: error: {message} (see '{where} --help')", err=True)
            code = exc.exit_code
        except click_api.exceptions.ClickException as exc:
            typer.echo(f"moseg: error: {one_line(exc.format_message())}", err=True)
            code = exc.exit_code
        except typer.Abort:
            typer.echo("moseg: error: interrupted", err=True)
            code = INTERRUPTED
        if standalone_mode:
            sys.exit(code)
        return code


app = typer.Typer(
    name="moseg",
    cls=_MosegGroup,
    help="Motion segmentation of tracked points with SubspaceNet: clips, image pairs, folders of clips.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",  # docstring paragraphs wrap to the terminal instead of keeping source line breaks
)


F = TypeVar("F", bound=Callable[..., Any])


@contextlib.contextmanager
def _quiet_ends() -> Any:
    """A closed stdout -> exit 0 with nothing printed; Ctrl-C -> one line and exit 130."""
    try:
        yield
    except BrokenPipeError:
        if not _stdout_closed():
            raise
        _silence_stdout()
        raise typer.Exit(0) from None
    except KeyboardInterrupt:
        _WARNINGS.drop()
        typer.echo("moseg: error: interrupted", err=True)
        raise typer.Exit(INTERRUPTED) from None
    except SystemExit as exc:
        # Rich (the help pages) meets a closed stdout by pointing it at /dev/null and exiting with 1.
        if exc.code == 1 and isinstance(exc.__context__, BrokenPipeError):
            raise typer.Exit(0) from None
        raise


def exit_with_error(message: str, code: int = 1) -> None:
    _WARNINGS.drop()
    typer.echo(f"moseg: error: {message}", err=True)
    raise typer.Exit(code=code)


def shown_path(name: object) -> str:
    """A path as the user knows it: `OUT/file`, not the temporary `.OUT.partial/.file.1a2b3c4d.tmp`."""
    text = re.sub(r"(^|/)\.([^/]+)\.partial(?=/|$)", r"\1\2", os.fsdecode(name))  # type: ignore[arg-type]
    return re.sub(r"(^|/)\.([^/]+)\.[0-9a-f]{8}\.tmp(\.[^/.]*)?$", r"\1\2\3", text)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (its terminal closed), raised in the main thread like Ctrl-C so that the same
    clean-up runs (no .partial folder left behind)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_RECEIVED: list[int] = []
"""The signal that stopped the running command (see _stop)."""


def _stop(signum: int, frame: Any) -> None:
    """The handler of Ctrl-C, SIGTERM and SIGHUP while a command runs: the first one stops it (a
    KeyboardInterrupt in the main thread); the ones after it are ignored, so that they cannot cut
    the clean-up short (a second Ctrl-C inside a closing generator printed "Exception ignored in"
    and a traceback). The signal is also recorded: Ray's waits turn the exception into a plain
    KeyboardInterrupt."""
    for other in STOP_SIGNALS:
        signal.signal(other, signal.SIG_IGN)
    _RECEIVED[:] = [signum]
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def report_stopped(exc: KeyboardInterrupt) -> None:
    """Ctrl-C, SIGTERM or SIGHUP -> one line, exit code 128 + the signal. After SIGHUP the terminal
    may be gone: a line that cannot be written is not an error, and stdout is pointed at /dev/null
    so that its flush at exit does not fail either."""
    signum = exc.signum if isinstance(exc, Terminated) else (_RECEIVED or [signal.SIGINT])[0]
    if signum == signal.SIGINT:
        exit_with_error("interrupted", INTERRUPTED)
    name = signal.Signals(signum).name
    try:
        sys.stdout.flush()
    except OSError:  # EIO: no terminal to write to
        _silence_stdout()
    try:
        exit_with_error(f"terminated ({name})", 128 + signum)
    except OSError:  # stderr went with the terminal
        raise typer.Exit(code=128 + signum) from None


@contextlib.contextmanager
def _signal_policy() -> Iterator[None]:
    """Ctrl-C, SIGTERM and SIGHUP handled by `_stop` while the command runs (in the main thread;
    elsewhere signals cannot be handled and Python's own handling stays)."""
    previous: dict[int, Any] = {}
    _RECEIVED.clear()
    try:
        for signum in STOP_SIGNALS:
            previous[signum] = signal.signal(signum, _stop)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class _DeferredWarnings(logging.Handler):
    """Holds the library's warnings until the command ends.

    After a success they are printed (`moseg: warning: ...`, at most `limit`, then a count); after a
    failure they are dropped, so that stderr holds only the one error line (a blank video in
    whole-video mode would otherwise print a warning per window before its error).
    """

    def __init__(self, limit: int = 10) -> None:
        super().__init__(logging.WARNING)
        self.limit = limit
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def drop(self) -> None:
        self.records.clear()

    def show(self) -> None:
        """Prints the warnings held, each text once (a folder searched twice warns twice about one link)."""
        records, self.records = self.records, []
        lines = list(dict.fromkeys(one_line(record.getMessage()) for record in records))
        for line in lines[: self.limit]:
            typer.echo(f"moseg: warning: {line}", err=True)
        if len(lines) > self.limit:
            typer.echo(f"moseg: warning: ... and {len(lines) - self.limit} more warnings (-v shows them)", err=True)


_WARNINGS = _DeferredWarnings()


def friendly(fn: F) -> F:
    """Turns MosegError, OS errors (a full disk, a read-only folder), Ctrl-C, SIGTERM and SIGHUP into
    one line on stderr and exit code 1 (128 + the signal for a signal: 130, 143, 129); a stdout
    closed by its reader ends quietly with 0 (see _MosegGroup). The library's warnings are shown
    after a success only. Anything else is a bug and keeps its traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _WARNINGS.drop()
        with _signal_policy():  # until the error line is out: a second signal is ignored
            try:
                result = fn(*args, **kwargs)
                _WARNINGS.show()
                return result
            except MosegError as exc:
                exit_with_error(one_line(str(exc)))
            except BrokenPipeError:
                if _stdout_closed():  # the reader of our output went away: not an error of ours
                    raise
                exit_with_error("Broken pipe")
            except OSError as exc:
                where = f"{shown_path(exc.filename)}: " if exc.filename else ""
                exit_with_error(f"{where}{exc.strerror or exc}")
            except KeyboardInterrupt as exc:
                report_stopped(exc)

    return wrapper  # type: ignore[return-value]


def _quiet_native_logs() -> None:
    """Keeps FFmpeg's, OpenCV's and libpng's own messages off stderr (runtime.quiet_native_logs).

    FFmpeg inside OpenCV prints decoder complaints ("moov atom not found", "cinepak_decode failed")
    straight to file descriptor 2, OpenCV its warnings ("can't open camera by index") and errors (a
    corrupt PNG); the failure they lead to is reported once, as a moseg error line. A value the user
    set in the environment wins.
    """
    from mosegpipe.runtime import quiet_native_logs

    quiet_native_logs()


def setup_run(threads: int, verbose: bool, *preload: str) -> None:
    """Logging, native log levels and thread counts; then `preload`, the modules the command imports
    next (names for importlib), imported with the collector paused (see runtime.collector_paused)."""
    from mosegpipe.runtime import collector_paused, set_threads

    root = logging.getLogger()
    if root.handlers and all(h is _WARNINGS for h in root.handlers) and verbose:
        root.removeHandler(_WARNINGS)  # an earlier command in this process deferred its warnings
    if verbose:
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    else:
        if _WARNINGS not in root.handlers:
            root.addHandler(_WARNINGS)
        root.setLevel(logging.WARNING)
        _quiet_native_logs()
    with collector_paused("cv2"):
        set_threads(threads)  # imports OpenCV
        for name in preload:
            importlib.import_module(name)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"moseg {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """moseg: which tracked points move together, dense masks and a Rerun recording."""
