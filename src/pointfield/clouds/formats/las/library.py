"""laspy, lazrs and LASzip failures as FormatErrors naming the file, without Rust's panic report."""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pointfield.errors import FormatError

# Rust's panic hook writes "thread '...' panicked at <source>:\n<message>\n" and a backtrace or a
# note on how to get one to file descriptor 2, before pyo3 turns the panic into an exception.
_PANIC_REPORT = re.compile(
    rb"thread '[^'\n]*'[^\n]* panicked at [^\n]*\n.*?(?:^note: [^\n]*\n|\Z)", re.DOTALL | re.MULTILINE
)


@contextmanager
def library_errors(path: Path, action: str) -> Iterator[None]:
    """Turn whatever laspy or lazrs raise into a FormatError naming the file.

    They raise LaspyException, ValueError, struct.error, EOFError, UnicodeDecodeError,
    LazrsError, MemoryError for sizes read from garbage, and pyo3's PanicException for Rust
    panics, which derives from BaseException; only interpreter exits pass through.
    """
    try:
        yield
    except (FormatError, KeyboardInterrupt, SystemExit, GeneratorExit):
        raise
    except BaseException as error:  # lazrs panics are BaseExceptions (see docstring)
        reason = str(error).strip().splitlines()
        detail = reason[0][:200] if reason else ""
        raise FormatError(path, f"{action}: {type(error).__name__} {detail}".rstrip()) from error


class _Stderr:
    """File descriptor 2 sent to a temporary file while any thread is inside lazrs.

    The descriptor is the process's, so the threads share one capture: the first in starts it,
    the last out ends it and writes back what others printed meanwhile, panic reports removed.
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.users = 0
        self.saved: int | None = None
        self.capture = None

    def enter(self) -> None:
        with self.lock:
            if self.users == 0:
                if sys.stderr is not None:
                    sys.stderr.flush()
                try:
                    self.saved = os.dup(2)
                except OSError:  # no standard error to guard (a daemon's)
                    self.saved = None
                else:
                    # Closed in exit(), when the last thread leaves lazrs.
                    self.capture = tempfile.TemporaryFile()  # noqa: SIM115
                    os.dup2(self.capture.fileno(), 2)
            self.users += 1

    def exit(self) -> None:
        with self.lock:
            self.users -= 1
            if self.users or self.saved is None:
                return
            os.dup2(self.saved, 2)
            os.close(self.saved)
            self.capture.seek(0)
            printed = _PANIC_REPORT.sub(b"", self.capture.read())
            self.capture.close()
            self.saved = self.capture = None
        if printed:
            os.write(2, printed)


_STDERR = _Stderr()


@contextmanager
def rust_panics_quiet() -> Iterator[None]:
    """Keep the report Rust prints when lazrs panics off the terminal.

    The panic still raises (pyo3's PanicException, which :func:`library_errors` turns into a
    FormatError); only the text Rust's panic hook writes to standard error is dropped. Anything
    else written to standard error meanwhile is written there when the block ends.
    """
    _STDERR.enter()
    try:
        yield
    finally:
        _STDERR.exit()
