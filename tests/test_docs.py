"""The docs stay true to the tool: every `moseg ...` command in the README's and docs/*.md's code blocks
parses against the CLI (an unknown command or option, a bad choice or a value of the wrong type fails
here), the commands of one page can be run in the order they are printed (no command writes the default
output folder of an earlier one without `--overwrite`), the README's set-up command is `.ci/run`'s, and
the links from docs/RESULTS.md into docs/HISTORY.md land on a heading. Nothing is run: each command is
resolved to its subcommand and parsed with click's `make_context`, as `moseg` would before calling it.
"""

from __future__ import annotations

import enum
import functools
import re
import shlex
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer

from mosegpipe.cli.app import click_api as click  # typer's own click where it ships one
from mosegpipe.cli.main import app

ROOT = Path(__file__).resolve().parents[1]
PAGES = [
    "README.md",
    "docs/CLI.md",
    "docs/RESULTS.md",
    "docs/OUTPUTS.md",
    "docs/SCALING.md",
    "docs/HOW-IT-WORKS.md",
    "docs/TRAINING.md",
    "samples/README.md",
]
PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.[A-Za-z]+)?$")  # OUT, CLIP, N, SECONDS, FILE.npz ...
SHELL_LANGS = {"", "bash", "sh", "shell", "console"}


def code_blocks(text: str) -> Iterator[tuple[str, list[str]]]:
    """(language, lines) of every fenced code block."""
    lang: str | None = None
    lines: list[str] = []
    for line in text.splitlines():
        fence = re.match(r"^\s*```(\S*)", line)
        if fence and lang is None:
            lang, lines = fence.group(1), []
        elif fence:
            yield lang, lines
            lang = None
        elif lang is not None:
            lines.append(line)


def inline_commands(page: str) -> list[str]:
    """Every `moseg ...` code span in a page's text (outside code blocks)."""
    text = re.sub(r"(?ms)^\s*```.*?^\s*```", "", (ROOT / page).read_text(encoding="utf-8"))
    spans = re.findall(r"(?<!`)`(moseg [^`]+)`(?!`)", text)
    return [
        part.strip() for span in spans for part in re.split(r"\|(?!\|)|&&|;", span) if part.strip().startswith("moseg")
    ]


def moseg_commands(page: str) -> list[str]:
    """Every `moseg ...` command in the shell code blocks of a page, in order, comments and prompts removed."""
    commands = []
    for lang, lines in code_blocks((ROOT / page).read_text(encoding="utf-8")):
        if lang not in SHELL_LANGS:
            continue
        for line in lines:
            line = re.sub(r"^\s*\$\s+", "", line)
            for part in re.split(r"\|(?!\|)|&&|;", line):
                part = part.strip()
                if re.match(r"^moseg(\s|$)", part):
                    commands.append(re.sub(r"\s+#.*$", "", part).strip())
    return commands


def _words(command: str) -> list[str]:
    """The command's words without `moseg`, optional brackets opened (`[--k N]` -> `--k N`) and `a|b|c`
    choices read as their first value."""
    words = shlex.split(command.replace("[", " ").replace("]", " "))[1:]
    return [w.split("|")[0] if "|" in w and not w.startswith("|") else w for w in words]


def _sample(param: Any) -> str:
    """A value of the parameter's type (Typer's annotation), for a placeholder such as N or SECONDS."""
    kind = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    kinds = [k for k in typing.get_args(kind) if k is not type(None)] or [kind]
    kind = kinds[0]
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return str(next(iter(kind)).value)
    if kind in (int, float):
        return str(param.min if param.min is not None else kind(1))
    return "placeholder"


def _fill(name: str, command: Any, words: list[str]) -> list[str]:
    """Placeholders (N, SECONDS, PROTOCOL, ...) replaced by a value of their option's or argument's type."""
    by_opt = {opt: p for p in command.params for opt in p.opts}
    arguments = [p for p in command.params if p.param_type_name == "argument"]
    out: list[str] = []
    expects: Any = None  # the option whose value comes next
    position = 0
    for word in words:
        param = expects
        if expects is None and not word.startswith("-") or word == "-":
            param = arguments[min(position, len(arguments) - 1)] if arguments else None
            position += 1
        expects = None
        if word.startswith("--") and "=" not in word or re.match(r"^-[a-z]$", word):
            option = by_opt.get(word)
            expects = option if option is not None and not getattr(option, "is_flag", False) else None
        elif param is not None and PLACEHOLDER.match(word):
            word = _sample(param) if _sample(param) != "placeholder" else word
        out.append(word)
    return out


@functools.cache
def _group() -> Any:
    """The click group behind `moseg` (built once: Typer builds it afresh on every call)."""
    return typer.main.get_command(app)


def parse(command: str) -> tuple[str, Any]:
    """Parse a documented command as `moseg` would: the subcommand, then its options and arguments."""
    group = _group()
    words = _words(command)
    assert words, f"{command!r}: no subcommand"
    name = words[0]
    sub = group.get_command(click.Context(group), name)
    assert sub is not None, f"{command!r}: 'moseg {name}' is not a command"
    parent = click.Context(group, info_name="moseg")
    return name, sub.make_context(name, _fill(name, sub, words[1:]), parent=parent, resilient_parsing=False)


def _with_config(folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Work in `folder`, with docs/CLI.md's example TOML as moseg.toml: `--config moseg.toml` checks its keys."""
    monkeypatch.chdir(folder)
    toml = next(
        lines for lang, lines in code_blocks((ROOT / "docs/CLI.md").read_text(encoding="utf-8")) if lang == "toml"
    )
    (folder / "moseg.toml").write_text("\n".join(toml) + "\n", encoding="utf-8")


BLOCKS = [(page, command) for page in PAGES for command in moseg_commands(page)]
SPANS = [(page, command) for page in PAGES for command in inline_commands(page) if not re.search(r"\.\.\.|…", command)]
# Commands the docs print as examples of a usage error (exit code 2): they must keep failing.
USAGE_ERRORS = {"moseg eval kitti", "moseg run clip.mp4 --frames 0", "moseg run clip.mp4 --k-method elbow"}
DOCUMENTED = [(page, command) for page, command in BLOCKS + SPANS if command not in USAGE_ERRORS]


def test_the_pages_hold_commands() -> None:
    assert len(moseg_commands("README.md")) >= 15
    assert len(moseg_commands("docs/CLI.md")) >= 10
    assert len(SPANS) >= 50


@pytest.mark.parametrize(("page", "command"), DOCUMENTED, ids=[f"{p}:{c[:60]}" for p, c in DOCUMENTED])
def test_documented_command_parses(page: str, command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if "--help" in command.split() or "--version" in command.split() or "--install-completion" in command:
        return
    _with_config(tmp_path, monkeypatch)
    try:
        parse(command)
    except click.exceptions.MissingParameter:
        # A span in the text may name a command without its arguments ("`moseg batch` resumes").
        if (page, command) in BLOCKS:
            raise
    except Exception as exc:  # a ClickException, or the library's validation error behind a callback
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        pytest.fail(f"{page}: {command!r} does not parse: {message}")


def test_the_parser_rejects_what_moseg_rejects() -> None:
    for bad in ("moseg runn clip.mp4", "moseg run clip.mp4 --framez 5", "moseg eval davis --baselines", *USAGE_ERRORS):
        with pytest.raises(Exception):  # noqa: B017 (a ClickException, or the validation error behind a callback)
            parse(bad)


def default_out(name: str, ctx: Any) -> str | None:
    """The folder a documented run/pair/tracks/replay writes (cli.common.default_out_here, default_out), or None."""
    p = ctx.params
    if p.get("out") is not None:
        return str(p["out"])
    source = {"run": "clip", "pair": "img1", "tracks": "file"}.get(name)
    if source is not None and p.get(source) is not None:
        path = Path(str(p[source]))
        return path.stem + ("_pair_moseg" if name == "pair" else "_moseg")  # in the current folder
    if name == "replay" and p.get("summary") is not None:
        run = Path(str(p["summary"])).parent
        return str(run.with_name(run.name + "_replay"))
    return None


@pytest.mark.parametrize("page", ["README.md", "docs/CLI.md", "samples/README.md"])
def test_examples_run_in_order(page: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No example writes an output folder an earlier one of the page wrote, unless it says --overwrite."""
    _with_config(tmp_path, monkeypatch)
    written: dict[str, str] = {}
    for command in moseg_commands(page):
        name, ctx = parse(command)
        if name not in ("run", "pair", "tracks", "replay"):
            continue
        out = default_out(name, ctx)
        if out is None or ctx.params.get("overwrite"):
            continue
        assert out not in written, f"{page}: {command!r} writes {out}, which {written.get(out)!r} wrote"
        written[out] = command


def test_readme_setup_is_what_ci_runs() -> None:
    ci = [line for line in (ROOT / ".ci/run").read_text().splitlines() if line and not line.startswith("#")]
    ci_command = ci[-1]
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    quick = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    setup = [
        line
        for lang, lines in code_blocks(quick)
        if lang in SHELL_LANGS
        for line in lines
        if line.startswith("python3 -m venv")
    ]
    assert len(setup) == 2, setup
    try_it, test = setup
    assert test == ci_command, f"README's test command differs from .ci/run's:\n{test}\n{ci_command}"
    install = ci_command.split(" && pip install '.[test,ray]'")[0]
    assert try_it.startswith(install + " && pip install . && moseg "), try_it


def _anchors(text: str) -> set[str]:
    """GitHub's anchors of a page's headings (code blocks skipped)."""
    seen: dict[str, int] = {}
    out = set()
    inside = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            inside = not inside
            continue
        heading = re.match(r"^#{1,6} (.*)", line)
        if inside or not heading:
            continue
        slug = re.sub(r"[^\w\- ]", "", heading.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_links_into_history_land_on_headings() -> None:
    history = _anchors((ROOT / "docs/HISTORY.md").read_text(encoding="utf-8"))
    for page in ("docs/RESULTS.md", "README.md"):
        text = (ROOT / page).read_text(encoding="utf-8")
        for anchor in re.findall(r"HISTORY\.md#([^)\s]+)", text):
            assert anchor in history, f"{page}: HISTORY.md#{anchor} is no heading"
        results = _anchors((ROOT / "docs/RESULTS.md").read_text(encoding="utf-8"))
        for anchor in re.findall(r"RESULTS\.md#([^)\s]+)", text):
            assert anchor in results, f"{page}: RESULTS.md#{anchor} is no heading"
