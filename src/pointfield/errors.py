"""One exception family for everything pointfield raises on purpose.

Catch :class:`PointfieldError` to handle any of them; the command line prints its message as one
line and exits non-zero.
"""

from __future__ import annotations

import os


class PointfieldError(Exception):
    """Base class of every error pointfield raises deliberately.

    Its message names settings as a Python caller spells them (``resume=True``, ``out``). Where
    the command line spells them otherwise, ``command_line`` is the message as the command
    prints it (``--resume``, ``--out``); library code never prints command-line flags itself.
    """

    def __init__(self, *args: object, command_line: str | None = None):
        super().__init__(*args)
        self.command_line = command_line


class FormatError(PointfieldError, ValueError):
    """A file is malformed, truncated, hostile, or not in the format it claims.

    The message always starts with the file's path, then says what was wrong and, where it helps,
    what was expected: ``"scan.pcd: header says 10 points of 16 bytes but only 12 bytes follow"``.
    """

    def __init__(self, path: str | os.PathLike[str], message: str):
        self.path = os.fspath(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}")

    def __reduce__(self):
        # Pickled by its own arguments, so that it crosses from a Dask worker process whole
        # (the default rebuilds it from the one joined message, which __init__ refuses).
        return type(self), (self.path, self.reason)


class OptionError(PointfieldError, ValueError):
    """An option's value cannot be used (``--memory lots``, a budget below the minimum); the message
    names the option, the value given and what was expected."""
