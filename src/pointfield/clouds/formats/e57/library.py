"""pye57 and libE57: the lazy import, their failures as FormatErrors, and the buffers they pass."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.errors import FormatError, PointfieldError

# pye57 hands buffers to libE57 by their struct code and only knows b B h H q ? f d for
# numbers ('l' is taken for 32 bits), so wider integers travel as long long ('q').
BUFFER_DTYPES = {np.dtype(t) for t in ("u1", "i1", "u2", "i2", "f4", "f8")}
LONG_LONG = np.dtype("q")


def load_pye57(path: Path) -> Any:
    """pye57, for reading or writing ``path``.

    Imported here, when an E57 file is met, rather than at the top: pye57 is an optional
    dependency (a compiled libE57), and every other format must work without it.
    """
    try:
        import pye57
    except ImportError:
        raise PointfieldError(
            f"{path}: E57 files need pye57; install it with: pip install 'pointfield[e57]'"
        ) from None
    return pye57


@contextmanager
def library_errors(path: Path, action: str) -> Iterator[None]:
    """Turn whatever pye57 / libE57 raise into a FormatError naming the file.

    libE57's messages carry several lines of debug context; the first line says what was wrong.
    """
    try:
        yield
    except (FormatError, PointfieldError):
        raise
    except Exception as error:
        lines = str(error).strip().splitlines()
        detail = lines[0][:200] if lines else type(error).__name__
        raise FormatError(path, f"{action}: {detail}") from error


def buffer_array(values: np.ndarray) -> np.ndarray:
    """``values`` in a dtype pye57 passes to libE57 intact (see BUFFER_DTYPES)."""
    if values.dtype.kind == "f":
        dtype = np.float32 if values.dtype.itemsize <= 4 else np.float64
        return np.ascontiguousarray(values, dtype)
    if values.dtype in BUFFER_DTYPES:
        return np.ascontiguousarray(values)
    array = np.empty(len(values), LONG_LONG)
    array[...] = values
    return array
