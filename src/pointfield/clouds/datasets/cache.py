"""The on-disk cache of sampled clouds, so that meshes are surface-sampled once, not every run.

One ``.npz`` (``points``, ``normals``) per source file, named by a digest of the file's
resolved path, size, modification time and the sampling settings: an edited file or a new
point count misses, and stale entries are simply never read again. Entries are written
atomically, so concurrent DataLoader workers or runs never see half a file.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud

# Files worth caching: meshes (sampled) and ModelNet's text files (slow to parse).
CACHED_SUFFIXES = (".off", ".ply", ".txt")


def default_cache_dir() -> Path:
    """Where sampled meshes are cached: ``$POINTFIELD_CACHE``, else ``~/.cache/pointfield``."""
    return Path(os.environ.get("POINTFIELD_CACHE") or Path.home() / ".cache" / "pointfield")


class SampleCache:
    """Sampled clouds under ``folder``, for one choice of ``settings`` (part of every key)."""

    def __init__(self, folder: str | os.PathLike[str], settings: str):
        self.folder = Path(folder)
        self.settings = settings

    def entry(self, path: Path) -> Path:
        """The cache file of ``path`` as it is now (its size and modification time included)."""
        stat = path.stat()
        key = f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{self.settings}"
        digest = hashlib.sha1(key.encode()).hexdigest()[:20]
        return self.folder / digest[:2] / f"{path.stem}.{digest}.npz"

    def load(self, entry: Path) -> PointCloud | None:
        """The cloud stored at ``entry``, or None when there is none or it cannot be read."""
        if not entry.is_file():
            return None
        try:
            with np.load(entry, allow_pickle=False) as stored:
                return PointCloud(stored["points"], {"normals": stored["normals"]})
        except (OSError, ValueError, KeyError):
            entry.unlink(missing_ok=True)  # unreadable entries are recomputed
            return None

    def store(self, entry: Path, cloud: PointCloud) -> None:
        """Keep ``cloud``'s points and normals at ``entry``."""
        entry.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(entry) as tmp, open(tmp, "wb") as file:
            np.savez(file, points=cloud.points, normals=cloud.fields["normals"])
