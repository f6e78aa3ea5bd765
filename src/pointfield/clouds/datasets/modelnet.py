"""ModelNet10 / ModelNet40 as a dataset, from whichever of its three distributions a folder holds.

:func:`modelnet_source` tells the distributions apart; :class:`ModelNet` reads raw OFF meshes
through :class:`~.folder.CloudFolder`, and the ``modelnet40_normal_resampled`` text files and
the ``ply_hdf5_2048`` HDF5 files itself.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.base import SPLITS, InMemoryClouds
from pointfield.clouds.datasets.cache import default_cache_dir
from pointfield.clouds.datasets.folder import CloudFolder
from pointfield.clouds.datasets.loading import (
    DEFAULT_MESH_POINTS,
    FileLoader,
    clean_cloud,
    load_or_skip,
    with_progress,
)
from pointfield.errors import FormatError, PointfieldError

MODELNET_TXT_POINTS = 2048


class ModelNet(InMemoryClouds):
    """ModelNet10 or ModelNet40, read from whichever of its distributions ``root`` holds.

    - **raw OFF** (``<class>/train/*.off``, ``<class>/test/*.off``, as Princeton ships it):
      each mesh is surface-sampled once with ``points_per_shape`` points and normals, and the
      samples are cached under ``cache_dir`` (default :func:`default_cache_dir`); this is a
      :class:`CloudFolder` underneath, with its rules for missing splits and bad files.
    - **modelnet40_normal_resampled** (``modelnet40_shape_names.txt``,
      ``modelnet40_{train,test}.txt`` listing ids like ``airplane_0001``, and
      ``<class>/<id>.txt`` with ``x,y,z,nx,ny,nz`` rows; the ``modelnet10_*`` lists select
      ModelNet10 with ``variant="modelnet10"``): the first ``points_per_shape`` (default 2048)
      points of each file are kept, with normals, and cached like the OFF samples.
    - **ply_hdf5_2048** (``ply_data_{train,test}<k>.h5`` with datasets ``data`` (S, 2048, 3),
      ``label`` (S, 1) and optionally ``normal``; class names from ``shape_names.txt``).
      Needs the ``h5py`` package.

    ``source`` says which was found: ``"off"``, ``"txt"`` or ``"h5"``.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str = "train",
        transform: Callable | None = None,
        *,
        seed: int = 0,
        points_per_shape: int | None = None,
        variant: str | None = None,
        cache_dir: str | os.PathLike[str] | None = None,
        on_error: str = "skip",
        progress: bool = False,
    ):
        super().__init__(transform, seed)
        if split not in SPLITS:
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        self.root = Path(root)
        if not self.root.is_dir():
            raise PointfieldError(f"{self.root}: no such folder")
        self.split = split
        self.source = modelnet_source(self.root)
        if self.source == "h5":
            self._load_h5(points_per_shape)
        elif self.source == "txt":
            self._load_txt(
                variant, points_per_shape or MODELNET_TXT_POINTS,
                cache_dir or default_cache_dir() / "modelnet", on_error, progress,
            )
        else:
            folder = CloudFolder(
                self.root, split, seed=seed, on_error=on_error,
                mesh_points=points_per_shape or DEFAULT_MESH_POINTS,
                cache_dir=cache_dir or default_cache_dir() / "meshes", progress=progress,
            )
            self.classes, self.clouds, self.labels = folder.classes, folder.clouds, folder.labels
            self.files, self.skipped, self.held_out = folder.files, folder.skipped, folder.held_out
        if not self.clouds:
            raise PointfieldError(f"{self.root}: no {split} shapes found ({self.source} layout)")

    def _load_h5(self, points_per_shape: int | None) -> None:
        # Imported here, not at the top: h5py is slow to import and only this distribution needs it.
        try:
            import h5py
        except ImportError:
            raise PointfieldError(
                "reading ModelNet's ply_hdf5_2048 files needs h5py: pip install h5py"
            ) from None
        files = sorted(self.root.glob(f"ply_data_{self.split}*.h5"))
        names_file = self.root / "shape_names.txt"
        names = _read_lines(names_file) if names_file.is_file() else None
        for path in files:
            try:
                with h5py.File(path, "r") as h5:
                    data = _h5_array(h5, "data", path)
                    label = _h5_array(h5, "label", path).reshape(-1).astype(np.int64)
                    normal = _h5_array(h5, "normal", path) if "normal" in h5 else None
            except OSError as error:
                raise FormatError(path, f"not a readable HDF5 file ({error})") from None
            if data.ndim != 3 or data.shape[2] != 3 or len(label) != len(data):
                raise FormatError(
                    path, f"expected data (S, N, 3) and label (S, 1); got data {data.shape}, "
                    f"label of {len(label)}"
                )
            if normal is not None and normal.shape != data.shape:
                raise FormatError(path, f"normal has shape {normal.shape}, data {data.shape}")
            for i in range(len(data)):
                points = data[i, :points_per_shape].astype(np.float32)
                fields = {} if normal is None else {
                    "normals": normal[i, :points_per_shape].astype(np.float32)
                }
                self.clouds.append(clean_cloud(PointCloud(points, fields), path))
                self.labels.append(int(label[i]))
                self.files.append(path)
        most = max(self.labels, default=-1)
        if names is not None and most >= len(names):
            raise FormatError(names_file, f"names {len(names)} classes but labels go to {most}")
        self.classes = names if names is not None else [f"class_{i}" for i in range(most + 1)]

    def _load_txt(
        self, variant: str | None, points: int, cache_dir, on_error: str, progress: bool
    ) -> None:
        variants = [v for v in ("modelnet40", "modelnet10")
                    if (self.root / f"{v}_shape_names.txt").is_file()]
        variant = variant or variants[0]
        if variant not in variants:
            raise PointfieldError(f"{self.root}: no {variant}_shape_names.txt")
        self.classes = _read_lines(self.root / f"{variant}_shape_names.txt")
        split_list = self.root / f"{variant}_{self.split}.txt"
        if not split_list.is_file():
            raise PointfieldError(f"{split_list}: split list not found")
        loader = FileLoader(points, points, None, cache_dir, keep_first=True)
        for shape_id in with_progress(_read_lines(split_list), progress, f"reading {variant}"):
            class_name = shape_id.rsplit("_", 1)[0]
            path = self.root / class_name / f"{shape_id}.txt"
            if class_name not in self.classes:
                raise FormatError(split_list, f"{shape_id!r} names no class of {variant}")
            cloud = load_or_skip(loader, path, on_error, self.skipped)
            if cloud is None:
                continue
            self.clouds.append(cloud)
            self.labels.append(self.classes.index(class_name))
            self.files.append(path)

    def describe(self) -> str:
        return (
            f"ModelNet {self.source} at {self.root} ({self.split}): {len(self)} shapes, "
            f"{len(self.classes)} classes"
        )


def modelnet_source(root: Path) -> str:
    """Which ModelNet distribution a folder holds: ``"h5"``, ``"txt"`` or ``"off"``."""
    if any(root.glob("ply_data_*.h5")):
        return "h5"
    if any(root.glob("modelnet*_shape_names.txt")):
        return "txt"
    return "off"


def _h5_array(h5, name: str, path: Path) -> np.ndarray:
    if name not in h5:
        raise FormatError(path, f"has no {name!r} dataset (expected data, label, normal)")
    return np.asarray(h5[name])


def _read_lines(path: Path) -> list[str]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise FormatError(path, f"cannot read the list: {error}") from None
    return [line.strip() for line in text.splitlines() if line.strip()]
