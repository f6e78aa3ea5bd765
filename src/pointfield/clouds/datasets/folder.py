"""A folder of point clouds and meshes as a dataset: :class:`CloudFolder`, and its layouts.

How classes and splits are found in a folder (:func:`discover`), and which files make the
train and test splits when the data has no test folder (:func:`choose_split`); reading each
file is :class:`~.loading.FileLoader`'s job.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from pointfield.clouds.datasets.base import PART_LABEL_FIELD, SPLITS, InMemoryClouds
from pointfield.clouds.datasets.loading import (
    DEFAULT_MESH_POINTS,
    FileLoader,
    load_or_skip,
    with_progress,
)
from pointfield.clouds.formats import formats
from pointfield.errors import PointfieldError

ON_ERROR = ("skip", "fail")
HOLDOUT_FRACTION = 0.2


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
        found = discover(self.root)
        if not found:
            raise PointfieldError(f"{self.root}: no point-cloud or mesh files found")
        self.classes = list(classes) if classes is not None else sorted(
            {name for _, name, _ in found if name is not None}
        )
        chosen, self.held_out = choose_split(found, split)
        loader = FileLoader(mesh_points, max_points, label_field, cache_dir)
        for path, class_name in with_progress(chosen, progress, f"reading {self.root.name}"):
            if class_name is not None and class_name not in self.classes:
                continue
            cloud = load_or_skip(loader, path, on_error, self.skipped)
            if cloud is None:
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


def discover(root: Path) -> list[tuple[Path, str | None, str | None]]:
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


def choose_split(
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
