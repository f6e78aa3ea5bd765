"""laspy and lazrs failures as FormatErrors naming the file."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pointfield.errors import FormatError


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
