"""Atomic file writes: a reader never sees a half-written file, and a crash loses nothing old."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` when the block succeeds.

    The temporary name keeps ``path``'s suffix, so libraries that choose an encoding by suffix
    (laspy writes LAZ for ``.laz``) behave as they would for the real name. On any exception the
    temporary file is removed and ``path`` is left as it was.

    Example::

        with atomic_path("scan.ply") as tmp:
            tmp.write_bytes(data)
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
