"""The exceptions mosegpipe raises. The CLI turns any MosegError into one line and exit code 1."""

from __future__ import annotations


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
