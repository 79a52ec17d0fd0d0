"""The exceptions mosegpipe raises on purpose, and the one rule for using them.

A `MosegError` means something the user supplied is wrong (a file, a folder, an argument, a setting);
the CLI turns it into one line on stderr and exit code 1. A bug in our code raises ValueError,
TypeError, ... and keeps its traceback: it must never be dressed up as a user error.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TypeVar

T = TypeVar("T")


class MosegError(Exception):
    """Base class of every error mosegpipe raises on purpose."""


class InputError(MosegError):
    """A file, folder or argument the user gave is missing, unreadable or invalid."""


class TooFewTracksError(MosegError):
    """Tracking or matching produced too few points to segment."""


class OutputExistsError(MosegError):
    """An output folder already holds results and overwriting was not asked for."""


class CheckpointError(MosegError):
    """A checkpoint file is missing, corrupt or does not fit the model."""


class DatasetError(MosegError):
    """A benchmark dataset folder is missing or malformed."""


class ConfigError(InputError, ValueError):
    """A setting names something that does not exist (a protocol, recipe, source, loss, method) or
    combines settings that cannot go together: an invalid argument (InputError) and an invalid value
    (ValueError)."""


def check_choice(what: str, value: str, choices: Iterable[str]) -> str:
    """Returns `value` if it is one of `choices`.

    Args:
        what: how the setting is named in the message (e.g. "--k-method").
        value: the value given.
        choices: the allowed values, in the order the message lists them.

    Raises:
        ConfigError: `value` is not among `choices`; the message names both.
    """
    allowed = list(choices)
    if value not in allowed:
        listed = " or ".join(f"'{c}'" for c in allowed) if len(allowed) <= 3 else ", ".join(allowed)
        raise ConfigError(f"{what} {value!r}: choose {listed}")
    return value


def lookup(registry: Mapping[str, T], name: str, what: str, sort: bool = False) -> T:
    """The entry called `name` of a registry (protocols, recipes, training sources).

    Args:
        registry: name -> entry.
        name: the name asked for.
        what: what an entry is, for the message ("protocol", "recipe", ...).
        sort: list the names sorted in the message (else in registry order).

    Raises:
        ConfigError: no entry has that name; the message lists the names.
    """
    if name not in registry:
        names = sorted(registry) if sort else list(registry)
        raise ConfigError(f"unknown {what} {name!r}; choose from {', '.join(names)}")
    return registry[name]
