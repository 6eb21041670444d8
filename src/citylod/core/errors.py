"""Errors that citylod raises for bad input and bad state.

Every error that reaches a user names the file (or source) and the problem. The command line turns a
`CitylodError` into one line on stderr and a non-zero exit; anything else is a bug and keeps its traceback.
This module imports nothing heavy.
"""

from __future__ import annotations

from os import PathLike


class CitylodError(Exception):
    """Base class for errors caused by input or configuration, not by a bug.

    Parameters
    ----------
    message
        What is wrong, in words a user understands.
    path
        The file or source concerned, if any; it is put in front of the message.
    """

    def __init__(self, message: str, path: str | PathLike[str] | None = None) -> None:
        self.path = None if path is None else str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class InputError(CitylodError):
    """An input file is unreadable, malformed, hostile or unsupported."""


class GeoreferenceError(InputError):
    """An input lacks the georeferencing (CRS, transform) that citylod needs."""


class EmptyInputError(InputError):
    """An input holds no usable data (all no-data, no points, no objects)."""


class UnsafePathError(InputError):
    """A tileset or other container points outside its own folder (``../``, absolute path, URL)."""


class PluginError(CitylodError):
    """A plugin failed to load or run."""
