"""Reading one file of a dataset into one clean cloud, by the rules :class:`CloudFolder` states.

:class:`FileLoader` reads a file with :func:`pointfield.read`, samples a mesh's surface,
drops non-finite points (:func:`clean_cloud`), takes part labels from a named field and bounds
the size of large clouds, going through a :class:`~.cache.SampleCache` when it has one.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pointfield.clouds import ops
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.base import PART_LABEL_FIELD
from pointfield.clouds.datasets.cache import CACHED_SUFFIXES, SampleCache
from pointfield.clouds.formats import read
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError, PointfieldError

DEFAULT_MESH_POINTS = 2048


class FileLoader:
    """Reads one file into a clean cloud, following :class:`CloudFolder`'s rules.

    ``keep_first`` keeps the first ``max_points`` points of a large cloud, as ModelNet's own
    loaders do with its text files, instead of an order-independent subset.
    """

    def __init__(
        self, mesh_points: int, max_points: int | None, label_field: str | None,
        cache_dir: str | os.PathLike[str] | None, keep_first: bool = False,
    ):
        self.mesh_points = mesh_points
        self.max_points = max_points
        self.label_field = label_field
        self.cache = (
            SampleCache(cache_dir, f"{mesh_points}|{max_points}") if cache_dir is not None else None
        )
        self.keep_first = keep_first

    def __call__(self, path: Path) -> PointCloud:
        entry = self._cache_entry(path)
        cached = self.cache.load(entry) if entry is not None else None
        if cached is not None:
            return cached
        cloud = self._read(path)
        # The cache holds points and normals only; clouds with more fields are read each time.
        if entry is not None and set(cloud.fields) == {"normals"}:
            self.cache.store(entry, cloud)
        return cloud

    def _read(self, path: Path) -> PointCloud:
        data = read(path)
        if not isinstance(data, PointCloud):
            raise FormatError(path, "holds records without x y z coordinates, not a point cloud")
        if isinstance(data, Mesh) and len(data.faces):
            seed = int.from_bytes(hashlib.sha1(path.name.encode()).digest()[:4], "little")
            try:
                cloud = data.sample_surface(self.mesh_points, seed=seed)
            except ValueError as error:
                raise FormatError(path, f"cannot sample the mesh surface: {error}") from None
        else:
            cloud = PointCloud(data.points, dict(data.fields))
        cloud = clean_cloud(cloud, path)
        if self.label_field is not None:
            if self.label_field not in cloud.fields:
                raise FormatError(path, f"has no per-point {self.label_field!r} field")
            labels = cloud.fields.pop(self.label_field)
            if labels.ndim != 1 or not np.issubdtype(labels.dtype, np.number):
                raise FormatError(path, f"field {self.label_field!r} is not one number per point")
            if np.issubdtype(labels.dtype, np.floating) and not np.all(labels == np.round(labels)):
                raise FormatError(path, f"field {self.label_field!r} holds non-integer values")
            cloud.fields[PART_LABEL_FIELD] = labels.astype(np.int64)
        if self.max_points is not None and len(cloud) > self.max_points:
            keep = (np.arange(self.max_points) if self.keep_first
                    else ops.canonical_sample(cloud.points, self.max_points))
            cloud = cloud.select(keep)
        return cloud

    def _cache_entry(self, path: Path) -> Path | None:
        """Cache entry of a mesh or ModelNet text file; None when caching does not apply."""
        if (
            self.cache is None
            or self.label_field is not None
            or path.suffix.lower() not in CACHED_SUFFIXES
        ):
            return None
        return self.cache.entry(path)


def load_or_skip(
    loader: FileLoader, path: Path, on_error: str, skipped: list[tuple[Path, str]]
) -> PointCloud | None:
    """``loader(path)``; a file that cannot be read raises (``on_error="fail"``) or is skipped.

    A skipped file is named in a warning and added to ``skipped`` with the reason; None is returned.
    """
    try:
        return loader(path)
    except (PointfieldError, OSError, ValueError) as error:
        reason = getattr(error, "reason", None) or str(error)
        if on_error == "fail":
            raise FormatError(path, reason) from error
        warnings.warn(f"{path}: skipped: {reason}", stacklevel=3)
        skipped.append((path, reason))
        return None


def clean_cloud(cloud: PointCloud, path: Path) -> PointCloud:
    """Drop non-finite points and zero non-finite normals; an empty result is a FormatError."""
    if len(cloud) == 0:
        raise FormatError(path, "has no points")
    finite = ops.finite_rows(cloud.points)
    if not finite.any():
        raise FormatError(path, f"none of its {len(cloud)} points has finite coordinates")
    if not finite.all():
        cloud = cloud.select(finite)
    if "normals" in cloud.fields:
        cloud.fields["normals"] = np.nan_to_num(
            cloud.fields["normals"], nan=0.0, posinf=0.0, neginf=0.0
        )
    return cloud


def with_progress(items: Sequence, show: bool, description: str):
    """``items``, wrapped in a progress bar when ``show`` and there are enough to wait for."""
    if not show or len(items) < 50:
        return items
    # Imported only when a bar is shown: tqdm.auto probes for a notebook front end on import.
    from tqdm.auto import tqdm

    return tqdm(items, desc=description, unit="file", leave=False)
