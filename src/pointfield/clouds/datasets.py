"""PyTorch datasets of labelled point clouds, and the collation of clouds into batches.

Every dataset here yields ``(cloud, label)``: a :class:`PointCloud` (after the dataset's
``transform``) and its class index into ``dataset.classes``. Per-point labels, for
segmentation, travel in the cloud as the integer field ``label`` (names in ``dataset.parts``),
so they follow their points through sampling and augmentation.

==================  ==========================================================================
:class:`CloudFolder`  a folder of files in any format :func:`pointfield.read` reads, one
                    subfolder per class, optional ``train`` / ``test`` subfolders
:class:`ModelNet`   ModelNet10 / 40 from raw OFF meshes, ``modelnet40_normal_resampled`` text
                    files, or ``ply_hdf5_2048`` HDF5 files
:class:`~pointfield.clouds.shapes.SyntheticShapes`  procedural shapes (built-in default)
==================  ==========================================================================

:class:`CloudCollate` turns a list of samples into a :class:`CloudBatch`: points padded to the
largest cloud, with a mask, so clouds of different sizes batch together.
"""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from pointfield.atomic import atomic_path
from pointfield.clouds import ops
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats import formats, read
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError, PointfieldError

SPLITS = ("train", "test")
ON_ERROR = ("skip", "fail")
HOLDOUT_FRACTION = 0.2
DEFAULT_MESH_POINTS = 2048
MODELNET_TXT_POINTS = 2048
PART_LABEL_FIELD = "label"


def default_cache_dir() -> Path:
    """Where sampled meshes are cached: ``$POINTFIELD_CACHE``, else ``~/.cache/pointfield``."""
    return Path(os.environ.get("POINTFIELD_CACHE") or Path.home() / ".cache" / "pointfield")


class CloudDataset(torch.utils.data.Dataset):
    """Base of the datasets: ``load(i)`` gives the raw sample, ``dataset[i]`` the transformed one.

    ``transform(cloud, rng)`` receives a generator seeded with ``(seed, epoch, i)``: augmentation
    is reproducible, independent of DataLoader workers, and new each epoch once the training
    loop calls :meth:`set_epoch`.

    Attributes every dataset sets: ``classes`` (class names, index = label), ``parts`` (names of
    the per-point labels, or None when clouds carry none) and ``root`` (where the data came
    from, or None).
    """

    classes: list[str]
    parts: list[str] | None = None
    root: Path | None = None

    def __init__(self, transform: Callable | None = None, seed: int = 0):
        self.transform = transform
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def load(self, index: int) -> tuple[PointCloud, int]:
        raise NotImplementedError

    def class_labels(self) -> np.ndarray:
        """``(len(self),)`` class index of every sample, without loading or transforming them."""
        raise NotImplementedError

    def __getitem__(self, index: int) -> tuple[PointCloud, int]:
        cloud, label = self.load(index)
        if self.transform is not None:
            cloud = self.transform(cloud, np.random.default_rng([self.seed, self.epoch, index]))
        return cloud, label

    def with_transform(self, transform: Callable | None) -> CloudDataset:
        """A shallow copy of this dataset (same loaded clouds) with another transform."""
        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.transform = transform
        return copy

    def describe(self) -> str:
        return f"{type(self).__name__}: {len(self)} clouds, {len(self.classes)} classes"


class InMemoryClouds(CloudDataset):
    """A dataset whose clouds were all loaded when it was built: ``clouds``, ``labels``, ``files``."""

    def __init__(self, transform: Callable | None = None, seed: int = 0):
        super().__init__(transform, seed)
        self.clouds: list[PointCloud] = []
        self.labels: list[int] = []
        self.files: list[Path] = []
        self.skipped: list[tuple[Path, str]] = []
        self.held_out = False

    def __len__(self) -> int:
        return len(self.clouds)

    def load(self, index: int) -> tuple[PointCloud, int]:
        return self.clouds[index], self.labels[index]

    def class_labels(self) -> np.ndarray:
        return np.asarray(self.labels, np.int64)


class CloudFolder(InMemoryClouds):
    """Point clouds and meshes in a folder, one subfolder per class.

    Layouts (files may sit deeper inside a class folder; hidden files and files of unknown
    suffix are ignored)::

        root/<class>/*.ply                    no split: see ``split`` below
        root/train/<class>/*, root/test/...   split folders above the classes
        root/<class>/train/*, .../test/*      split folders inside each class (ModelNet's)
        root/*.ply, root/train/*.ply          no class folders (segmentation data)

    ``split`` ``"train"`` or ``"test"`` picks files from those folders. When the data has no
    test files at all, the test split is held out of the rest instead: the last
    ``ceil(n / 5)`` files (in name order) of every class with at least two files;
    ``held_out`` is then True. ``split=None`` takes every file.

    Files are read once, when the dataset is built, with :func:`pointfield.read`:

    - A mesh is replaced by ``mesh_points`` points sampled uniformly over its surface (with
      its face normals), seeded by the file's name; with ``cache_dir`` the samples are cached
      there, keyed by file path, size, modification time and count, and written atomically.
    - Points with a NaN or infinite coordinate are dropped; non-finite ``normals`` become 0.
    - A cloud larger than ``max_points`` keeps an order-independent subset of that many
      (:func:`~pointfield.clouds.ops.canonical_sample`), to bound memory.
    - ``label_field`` names an integer per-point field to serve as part labels (stored as the
      ``label`` field, int64; ``parts`` are then ``"0" .. str(max)``).

    A file that cannot be read, is empty, has no finite point or lacks ``label_field`` is
    reported by name: with ``on_error="skip"`` a warning is issued and the file left out (all
    such files are listed in ``skipped``); with ``on_error="fail"`` a :class:`FormatError`
    naming it is raised.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str | None = None,
        transform: Callable | None = None,
        *,
        seed: int = 0,
        on_error: str = "skip",
        mesh_points: int = DEFAULT_MESH_POINTS,
        max_points: int | None = None,
        label_field: str | None = None,
        cache_dir: str | os.PathLike[str] | None = None,
        classes: Sequence[str] | None = None,
        progress: bool = False,
    ):
        super().__init__(transform, seed)
        if split not in (None, *SPLITS):
            raise ValueError(f"split must be None, 'train' or 'test', got {split!r}")
        if on_error not in ON_ERROR:
            raise ValueError(f"on_error must be 'skip' or 'fail', got {on_error!r}")
        self.root = Path(root)
        if not self.root.is_dir():
            raise PointfieldError(f"{self.root}: no such folder")
        self.split = split
        found = _discover(self.root)
        if not found:
            raise PointfieldError(f"{self.root}: no point-cloud or mesh files found")
        self.classes = list(classes) if classes is not None else sorted(
            {name for _, name, _ in found if name is not None}
        )
        chosen, self.held_out = _choose_split(found, split)
        loader = _FileLoader(mesh_points, max_points, label_field, cache_dir, self.root)
        for path, class_name in _progress(chosen, progress, f"reading {self.root.name}"):
            if class_name is not None and class_name not in self.classes:
                continue
            try:
                cloud = loader(path)
            except (PointfieldError, OSError, ValueError) as error:
                reason = getattr(error, "reason", None) or str(error)
                if on_error == "fail":
                    raise FormatError(path, reason) from error
                warnings.warn(f"{path}: skipped: {reason}", stacklevel=2)
                self.skipped.append((path, reason))
                continue
            self.clouds.append(cloud)
            self.labels.append(self.classes.index(class_name) if class_name is not None else -1)
            self.files.append(path)
        if label_field is not None:
            most = max((int(c.fields[PART_LABEL_FIELD].max(initial=0)) for c in self.clouds),
                       default=0)
            self.parts = [str(i) for i in range(most + 1)]

    def describe(self) -> str:
        split = f" ({self.split}{', held out' if self.held_out else ''})" if self.split else ""
        skipped = f", {len(self.skipped)} skipped" if self.skipped else ""
        return (
            f"{self.root}{split}: {len(self)} clouds, {len(self.classes)} classes{skipped}"
        )


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
                self.clouds.append(_clean(PointCloud(points, fields), path))
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
        loader = _FileLoader(points, points, None, cache_dir, self.root, keep_first=True)
        for shape_id in _progress(_read_lines(split_list), progress, f"reading {variant}"):
            class_name = shape_id.rsplit("_", 1)[0]
            path = self.root / class_name / f"{shape_id}.txt"
            if class_name not in self.classes:
                raise FormatError(split_list, f"{shape_id!r} names no class of {variant}")
            try:
                cloud = loader(path)
            except (PointfieldError, OSError, ValueError) as error:
                reason = getattr(error, "reason", None) or str(error)
                if on_error == "fail":
                    raise FormatError(path, reason) from error
                warnings.warn(f"{path}: skipped: {reason}", stacklevel=2)
                self.skipped.append((path, reason))
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


# ---------------------------------------------------------------------------------------------
# Batches
# ---------------------------------------------------------------------------------------------


@dataclass
class CloudBatch:
    """B clouds padded to a common size N, real points first.

    ``points`` ``(B, N, 3)`` float32; ``features`` ``(B, N, C)`` float32 extra per-point inputs
    (normals, ...) or None; ``mask`` ``(B, N)`` bool, True for real points, or None when every
    cloud has N points; ``labels`` ``(B,)`` int64 class indices; ``point_labels`` ``(B, N)``
    int64 part labels with -1 at padding, or None.
    """

    points: torch.Tensor
    labels: torch.Tensor
    features: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    point_labels: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.points)

    def to(self, device: torch.device | str) -> CloudBatch:
        def move(tensor: torch.Tensor | None) -> torch.Tensor | None:
            return None if tensor is None else tensor.to(device, non_blocking=True)

        return replace(
            self, points=move(self.points), labels=move(self.labels),
            features=move(self.features), mask=move(self.mask),
            point_labels=move(self.point_labels),
        )


class CloudCollate:
    """``collate(samples) -> CloudBatch`` for a DataLoader's ``collate_fn``.

    ``features`` names the per-point fields fed to the model besides xyz, in order (e.g.
    ``("normals",)``); their components are concatenated into ``CloudBatch.features``.
    ``point_labels`` True collects the ``label`` field for segmentation. A cloud with no points
    is an error here, never a silent NaN later.
    """

    def __init__(self, features: Sequence[str] = (), point_labels: bool = False):
        self.features = tuple(features)
        self.point_labels = point_labels

    def __call__(self, samples: Sequence[tuple[PointCloud, int]]) -> CloudBatch:
        sizes = [len(cloud) for cloud, _ in samples]
        if min(sizes) == 0:
            raise PointfieldError("a cloud in the batch has no points")
        batch, size = len(samples), max(sizes)
        points = torch.zeros(batch, size, 3)
        channels = sum(_channels(samples[0][0], name) for name in self.features)
        features = torch.zeros(batch, size, channels) if self.features else None
        point_labels = torch.full((batch, size), -1, dtype=torch.long) if self.point_labels else None
        mask = torch.zeros(batch, size, dtype=torch.bool)
        for row, (cloud, _) in enumerate(samples):
            n = len(cloud)
            points[row, :n] = torch.from_numpy(np.asarray(cloud.points, np.float32))
            mask[row, :n] = True
            if features is not None:
                columns = [_feature(cloud, name) for name in self.features]
                features[row, :n] = torch.from_numpy(np.concatenate(columns, axis=1))
            if point_labels is not None:
                if PART_LABEL_FIELD not in cloud.fields:
                    raise PointfieldError("a cloud in the batch has no per-point 'label' field")
                point_labels[row, :n] = torch.from_numpy(
                    cloud.fields[PART_LABEL_FIELD].astype(np.int64)
                )
        labels = torch.tensor([label for _, label in samples], dtype=torch.long)
        return CloudBatch(
            points, labels, features, None if min(sizes) == size else mask, point_labels
        )


def _channels(cloud: PointCloud, name: str) -> int:
    return _feature(cloud, name).shape[1]


def _feature(cloud: PointCloud, name: str) -> np.ndarray:
    if name not in cloud.fields:
        raise PointfieldError(f"a cloud has no {name!r} field to use as a feature")
    values = cloud.fields[name].reshape(len(cloud), -1).astype(np.float32)
    return np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0)


# ---------------------------------------------------------------------------------------------
# Loading files
# ---------------------------------------------------------------------------------------------


def _discover(root: Path) -> list[tuple[Path, str | None, str | None]]:
    """Every readable-looking file under ``root`` as (path, class or None, split or None)."""
    suffixes = {suffix for fmt in formats() for suffix in fmt.suffixes}

    def files_in(folder: Path) -> list[Path]:
        return sorted(
            path for path in folder.rglob("*")
            if path.is_file() and path.suffix.lower() in suffixes
            and not any(part.startswith(".") for part in path.relative_to(root).parts)
        )

    def subfolders(folder: Path) -> list[Path]:
        return sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))

    found = []
    split_tops = [root / s for s in SPLITS if (root / s).is_dir()]
    if split_tops:
        for top in split_tops:
            for path in files_in(top):
                inner = path.relative_to(top).parts
                found.append((path, inner[0] if len(inner) > 1 else None, top.name))
        return found
    for path in sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in suffixes):
        found.append((path, None, None))
    for folder in subfolders(root):
        inner_splits = [folder / s for s in SPLITS if (folder / s).is_dir()]
        if inner_splits:
            for split_folder in inner_splits:
                found += [(path, folder.name, split_folder.name) for path in files_in(split_folder)]
        else:
            found += [(path, folder.name, None) for path in files_in(folder)]
    return found


def _choose_split(
    found: list[tuple[Path, str | None, str | None]], split: str | None
) -> tuple[list[tuple[Path, str | None]], bool]:
    """The (path, class) pairs of ``split``, and whether the test split had to be held out."""
    if split is None:
        return [(path, name) for path, name, _ in found], False
    if any(declared == "test" for _, _, declared in found):
        # Files outside any split folder count as training data.
        wanted = {split} if split == "test" else {"train", None}
        return [(path, name) for path, name, declared in found if declared in wanted], False
    by_class: dict[str | None, list[Path]] = {}
    for path, name, _ in found:
        by_class.setdefault(name, []).append(path)
    chosen = []
    for name, paths in by_class.items():
        paths = sorted(paths, key=lambda p: p.name)
        held = math.ceil(len(paths) * HOLDOUT_FRACTION) if len(paths) >= 2 else 0
        part = paths[len(paths) - held:] if split == "test" else paths[: len(paths) - held]
        chosen += [(path, name) for path in part]
    return chosen, True


class _FileLoader:
    """Reads one file into a clean cloud, following :class:`CloudFolder`'s rules."""

    def __init__(
        self, mesh_points: int, max_points: int | None, label_field: str | None,
        cache_dir: str | os.PathLike[str] | None, root: Path, keep_first: bool = False,
    ):
        self.mesh_points = mesh_points
        self.max_points = max_points
        self.label_field = label_field
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.root = root
        self.keep_first = keep_first

    def __call__(self, path: Path) -> PointCloud:
        cached = self._cache_path(path)
        if cached is not None and cached.is_file():
            try:
                with np.load(cached, allow_pickle=False) as stored:
                    return PointCloud(stored["points"], {"normals": stored["normals"]})
            except (OSError, ValueError, KeyError):
                cached.unlink(missing_ok=True)  # unreadable cache entries are recomputed
        cloud = self._read(path)
        if cached is not None and set(cloud.fields) <= {"normals"} and "normals" in cloud.fields:
            cached.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(cached) as tmp, open(tmp, "wb") as file:
                np.savez(file, points=cloud.points, normals=cloud.fields["normals"])
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
        cloud = _clean(cloud, path)
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

    def _cache_path(self, path: Path) -> Path | None:
        """Cache entry of a mesh or ModelNet text file; None when caching does not apply."""
        if (
            self.cache_dir is None
            or self.label_field is not None
            or path.suffix.lower() not in (".off", ".ply", ".txt")
        ):
            return None
        stat = path.stat()
        key = f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{self.mesh_points}|{self.max_points}"
        digest = hashlib.sha1(key.encode()).hexdigest()[:20]
        return self.cache_dir / digest[:2] / f"{path.stem}.{digest}.npz"


def _clean(cloud: PointCloud, path: Path) -> PointCloud:
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


def _progress(items: Sequence, show: bool, description: str):
    if not show or len(items) < 50:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=description, unit="file", leave=False)
