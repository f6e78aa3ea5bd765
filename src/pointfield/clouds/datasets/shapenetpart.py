"""ShapeNetPart (Yi et al., SIGGRAPH Asia 2016), as PointNet++ distributes it: 16 categories, 50 parts.

Layout of ``shapenetcore_partanno_segmentation_benchmark_v0_normal``::

    root/synsetoffset2category.txt          "<Category>\\t<synset>" per line, e.g. "Airplane  02691156"
    root/train_test_split/shuffled_train_file_list.json   ["shape_data/02691156/1021a0914a7207aff927ed529ad90a11", ...]
    root/train_test_split/shuffled_val_file_list.json
    root/train_test_split/shuffled_test_file_list.json
    root/02691156/1021a0914a7207aff927ed529ad90a11.txt     rows "x y z nx ny nz part" (part as a float)

Part labels are global, 0..49, each category owning a fixed range (:data:`CATEGORY_PARTS`, the
table every reference implementation carries), so one segmenter serves all 16 categories, as
with pointfield's synthetic shapes; they are named ``<category> <k>``. The training split is the
official train and val lists together and the test split the test list, as PointNet++ trains.
Every cloud comes with its ``normals`` (``--normals`` feeds them to the model).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.base import PART_LABEL_FIELD, SPLITS, InMemoryClouds
from pointfield.clouds.datasets.loading import with_progress
from pointfield.clouds.formats import read
from pointfield.errors import FormatError, PointfieldError

CATEGORY_FILE = "synsetoffset2category.txt"
SPLIT_FOLDER = "train_test_split"
LISTS = {"train": ("train", "val"), "test": ("test",)}
# The global part labels of each category.
CATEGORY_PARTS = {
    "Airplane": (0, 1, 2, 3), "Bag": (4, 5), "Cap": (6, 7), "Car": (8, 9, 10, 11), "Chair": (12, 13, 14, 15),
    "Earphone": (16, 17, 18), "Guitar": (19, 20, 21), "Knife": (22, 23), "Lamp": (24, 25, 26, 27),
    "Laptop": (28, 29), "Motorbike": (30, 31, 32, 33, 34, 35), "Mug": (36, 37), "Pistol": (38, 39, 40),
    "Rocket": (41, 42, 43), "Skateboard": (44, 45, 46), "Table": (47, 48, 49),
}
PART_NAMES = [f"{category} {k}" for category, parts in CATEGORY_PARTS.items() for k in range(len(parts))]
COLUMNS = "x y z nx ny nz part"


def is_shapenetpart(root: Path) -> bool:
    return (root / CATEGORY_FILE).is_file() and (root / SPLIT_FOLDER).is_dir()


def read_categories(path: Path) -> dict[str, str]:
    """``{synset: category}`` from ``synsetoffset2category.txt``, in the file's order."""
    if not path.is_file():
        raise FormatError(path, "missing: it names the synset folder of each category")
    categories = {}
    for line_number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        words = line.split()
        if not words:
            continue
        if len(words) != 2 or words[0] not in CATEGORY_PARTS:
            raise FormatError(path, f"line {line_number}: expected '<Category> <synset>' with one of the 16 "
                                    f"categories, got {line.strip()!r}")
        categories[words[1]] = words[0]
    return categories


def read_file_list(path: Path) -> list[tuple[str, str]]:
    """``[(synset, shape id), ...]`` from a ``shuffled_*_file_list.json`` of ``shape_data/<synset>/<id>`` entries."""
    if not path.is_file():
        raise FormatError(path, "missing: the official split lists are needed")
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise FormatError(path, f"not valid JSON: {error}") from None
    if not isinstance(entries, list):
        raise FormatError(path, "expected a JSON list of 'shape_data/<synset>/<id>' strings")
    shapes = []
    for entry in entries:
        parts = entry.split("/") if isinstance(entry, str) else []
        if len(parts) != 3:
            raise FormatError(path, f"entry {entry!r} is not 'shape_data/<synset>/<id>'")
        shapes.append((parts[1], parts[2]))
    return shapes


class ShapeNetPart(InMemoryClouds):
    """The shapes of ShapeNetPart's ``split`` (train: the train and val lists), read when built.

    ``classes`` are the 16 categories in ``synsetoffset2category.txt``'s order, ``parts`` the 50
    global part names. ``categories`` keeps only those categories. A listed shape whose file is
    missing or malformed is skipped with a warning naming it (``on_error="skip"``) or raises
    (``"fail"``).
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str = "train",
        transform: Callable | None = None,
        *,
        seed: int = 0,
        on_error: str = "skip",
        categories: Sequence[str] | None = None,
        progress: bool = False,
    ):
        super().__init__(transform, seed)
        if split not in SPLITS:
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        self.root, self.split = Path(root), split
        if not is_shapenetpart(self.root):
            raise PointfieldError(f"{self.root}: not ShapeNetPart (expected {CATEGORY_FILE} and {SPLIT_FOLDER}/)")
        by_synset = read_categories(self.root / CATEGORY_FILE)
        self.classes = [c for c in by_synset.values() if categories is None or c in categories]
        self.parts = list(PART_NAMES)
        self.category_parts = [CATEGORY_PARTS[c] for c in self.classes]
        shapes = []
        for name in LISTS[split]:
            shapes += read_file_list(self.root / SPLIT_FOLDER / f"shuffled_{name}_file_list.json")
        shapes = [(s, i) for s, i in shapes if by_synset.get(s) in self.classes]
        for synset, shape in with_progress(shapes, progress, f"reading ShapeNetPart {split}"):
            path = self.root / synset / f"{shape}.txt"
            try:
                cloud = self._read_shape(path, by_synset[synset])
            except (PointfieldError, OSError) as error:
                if on_error == "fail":
                    raise
                warnings.warn(f"{path}: skipped: {getattr(error, 'reason', error)}", stacklevel=2)
                self.skipped.append((path, str(error)))
                continue
            self.clouds.append(cloud)
            self.labels.append(self.classes.index(by_synset[synset]))
            self.files.append(path)

    @staticmethod
    def _read_shape(path: Path, category: str) -> PointCloud:
        if not path.is_file():
            raise FormatError(path, "missing, though the split list names it")
        cloud = read(path, format="text", columns=COLUMNS)
        parts = cloud.fields["part"]
        if len(cloud) == 0:
            raise FormatError(path, "has no points")
        allowed = CATEGORY_PARTS[category]
        if not np.isin(parts, allowed).all():
            bad = parts[~np.isin(parts, allowed)][0]
            raise FormatError(path, f"part label {bad:g} is not one of {category}'s parts {list(allowed)}")
        fields = {"normals": cloud.fields["normals"].astype(np.float32), PART_LABEL_FIELD: parts.astype(np.int64)}
        return PointCloud(cloud.points.astype(np.float32), fields)

    def describe(self) -> str:
        skipped = f", {len(self.skipped)} skipped" if self.skipped else ""
        return f"ShapeNetPart {self.root} ({self.split}): {len(self)} shapes, {len(self.classes)} categories{skipped}"
