"""Labelled clouds in any format pointfield reads, as a scene dataset: :class:`LabelledClouds`.

Each file is one scan whose integer per-point field holds a class code: ``classification`` (LAS,
and what pointfield writes for it) or ``label`` (PLY and the rest), or any field named with
``label_field``. The class-name table is given once:

1. as ``classes`` (a list: code i is ``classes[i]``; or a dict ``{code: name}``), else
2. in a ``classes.json`` file (the same list or object) in the files' folder or the folder
   above it (as :func:`~pointfield.clouds.synthetic_scenes.make_scenes` writes it), else
3. for LAS ``classification``, the Classification Lookup VLR of the first training file that
   has one (ASPRS's class table in the header, as ``segment predict`` writes it), else
4. for LAS ``classification``, the ASPRS standard classes (2 ground, 6 building, ...) of the
   codes that occur in the training files, else
5. the codes that occur in the training files, named by their numbers.

Inside, labels are indices into ``classes`` (``codes[i]`` is class i's code in the files, so
predictions are written back in the files' own codes); a code outside the table is -1,
ignored. A folder with ``train/`` and ``test/`` subfolders gives the splits; a list of files
holds out its last fifth (by name); a single file holds out the points of its last fifth along
x (x above the 80th percentile), so one labelled tile can be trained and scored on.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.folder import discover
from pointfield.clouds.datasets.scene_base import LABEL_FIELD, SceneDataset, check_split
from pointfield.clouds.formats import read
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError, PointfieldError

CLASSES_FILE = "classes.json"
LAS_CLASS_LOOKUP = ("LASF_Spec", 0)
LABEL_FIELDS = ("classification", "label")
HOLDOUT_FRACTION = 0.2
# ASPRS standard point classes of LAS 1.4 (R15), table 17.
ASPRS_CLASSES = {
    0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation",
    5: "high vegetation", 6: "building", 7: "low point (noise)", 8: "model key-point", 9: "water", 10: "rail",
    11: "road surface", 12: "overlap", 13: "wire guard", 14: "wire conductor", 15: "transmission tower",
    16: "wire-structure connector", 17: "bridge deck", 18: "high noise",
}


def class_lookup_record(codes: Sequence[int], names: Sequence[str]) -> dict[str, Any]:
    """The ASPRS Classification Lookup VLR (user "LASF_Spec", record 0) of ``codes`` -> ``names``,
    as a record of ``metadata["las_vlrs"]``: 256 entries of a uint8 class and a 15-byte ASCII
    description (LAS 1.4 R15, "Other Specification Defined VLRs"), those of codes the run lacks
    empty; names are cut to 15 bytes, characters outside ASCII become '?'."""
    import laspy

    lookup = laspy.vlrs.known.ClassificationLookupVlr()
    for code in range(256):
        lookup[code] = ""
    for code, name in zip(codes, names, strict=True):
        lookup[int(code)] = name.encode("ascii", "replace").decode("ascii")[:15]
    return {"user_id": LAS_CLASS_LOOKUP[0], "record_id": LAS_CLASS_LOOKUP[1], "description": "Classification Lookup",
            "data": lookup.record_data_bytes()}


def read_class_lookup(metadata: dict[str, Any]) -> dict[int, str] | None:
    """``{code: name}`` from a LAS cloud's Classification Lookup VLR (entries with a description),
    or None. Descriptions are read up to their first NUL (laspy's own parser drops every character
    that is not a letter, digit or space, '_' and '-' included)."""
    for record in metadata.get("las_vlrs") or []:
        if (record.get("user_id"), record.get("record_id")) == LAS_CLASS_LOOKUP:
            data = bytes(record["data"])
            entries = np.frombuffer(data[: len(data) // 16 * 16], np.dtype([("code", "u1"), ("name", "S15")]))
            table = {int(e["code"]): e["name"].split(b"\0")[0].decode("ascii", "replace").strip() for e in entries}
            return {code: name for code, name in sorted(table.items()) if name} or None
    return None


def with_class_lookup(metadata: dict[str, Any], codes: Sequence[int], names: Sequence[str]) -> dict[str, Any]:
    """``metadata`` whose LAS VLRs hold the class table of ``codes`` (replacing any earlier one)."""
    vlrs = [r for r in metadata.get("las_vlrs") or [] if (r.get("user_id"), r.get("record_id")) != LAS_CLASS_LOOKUP]
    return {**metadata, "las_vlrs": [*vlrs, class_lookup_record(codes, names)]}


def read_class_table(path: Path) -> dict[int, str]:
    """``{code: name}`` from a ``classes.json`` holding a list of names or an object of code -> name."""
    try:
        table = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise FormatError(path, f"not a readable JSON class table: {error}") from None
    return _table_of(table, path)


def _table_of(table: Sequence[str] | Mapping, where: Path | str) -> dict[int, str]:
    try:
        if isinstance(table, Mapping):
            return {int(code): str(name) for code, name in table.items()}
        if isinstance(table, (list, tuple)) and all(isinstance(n, str) for n in table):
            return dict(enumerate(table))
    except (TypeError, ValueError):
        pass
    raise FormatError(where, 'expected a list of class names or an object {"code": "name"}')


def find_class_table(files: Sequence[Path]) -> Path | None:
    """The ``classes.json`` in the first file's folder or the folder above it, or None."""
    if not files:
        return None
    for folder in (files[0].parent, files[0].parent.parent):
        if (folder / CLASSES_FILE).is_file():
            return folder / CLASSES_FILE
    return None


def split_files(paths: Sequence[Path]) -> tuple[dict[str, list[Path]], bool]:
    """``({"train": files, "test": files}, whole_files)`` for DATA given as files and folders.

    A folder contributes its files (its ``train/`` and ``test/`` subfolders give the splits);
    without any test file, the last fifth of the files by name is held out, or, for a single
    file, part of its points (``whole_files`` False).
    """
    splits: dict[str, list[Path]] = {"train": [], "test": []}
    for path in paths:
        if path.is_dir():
            for file, _, declared in discover(path):
                splits["test" if declared == "test" else "train"].append(file)
        elif path.is_file():
            splits["train"].append(path)
        else:
            raise PointfieldError(f"{path}: no such file or folder")
    if splits["test"]:
        return splits, True
    files = sorted(splits["train"], key=lambda p: p.name)
    if len(files) == 1:
        return {"train": files, "test": files}, False
    held = math.ceil(len(files) * HOLDOUT_FRACTION)
    return {"train": files[: len(files) - held], "test": files[len(files) - held:]}, True


class LabelledClouds(SceneDataset):
    """Labelled clouds as scans (see the module doc).

    ``classes`` and ``codes``, when the caller knows them (a trained model's, or the training
    split's), fix the table; otherwise it is found as the module doc says.
    """

    def __init__(
        self,
        paths: Sequence[str | os.PathLike[str]],
        split: str = "train",
        *,
        label_field: str | None = None,
        classes: Sequence[str] | Mapping | None = None,
        codes: Sequence[int] | None = None,
    ):
        check_split(split)
        self.split = split
        given = [Path(p) for p in paths]
        if not given:
            raise PointfieldError("no labelled files given")
        self.root = given[0] if len(given) == 1 and given[0].is_dir() else None
        splits, self.whole_files = split_files(given)
        self.files = splits[split]
        if not self.files:
            raise PointfieldError(f"{', '.join(map(str, given))}: no {split} files")
        self.names = [p.stem for p in self.files] if self.whole_files else [f"{self.files[0].stem} ({split} part)"]
        self.label_field = label_field
        if classes is not None and codes is not None:
            self.classes, self.codes = list(classes), [int(c) for c in codes]
        elif classes is not None:
            table = _table_of(classes, "classes")
            self.codes, self.classes = list(table), list(table.values())
        else:
            self.codes, self.classes = self._find_table(splits["train"])

    def _find_table(self, train_files: Sequence[Path]) -> tuple[list[int], list[str]]:
        table_path = find_class_table(train_files)
        if table_path is not None:
            table = read_class_table(table_path)
            return list(table), list(table.values())
        present: set[int] = set()
        field = None
        for path in train_files:
            cloud, field = self._read_labelled(path)
            lookup = read_class_lookup(cloud.metadata) if field == "classification" else None
            if lookup:  # the table a LAS file carries in its header (segment predict writes it)
                return list(lookup), list(lookup.values())
            present |= set(np.unique(cloud.fields[field]).tolist())
        codes = sorted(int(c) for c in present if c >= 0)
        if field == "classification":
            return codes, [ASPRS_CLASSES.get(c, f"class {c}") for c in codes]
        return codes, [str(c) for c in codes]

    def _read_labelled(self, path: Path) -> tuple[PointCloud, str]:
        cloud = read(path)
        if not isinstance(cloud, PointCloud):
            raise FormatError(path, "holds records without x y z coordinates, not a point cloud")
        if isinstance(cloud, Mesh):
            cloud = PointCloud(cloud.points, cloud.fields, None, cloud.metadata)
        candidates = (self.label_field,) if self.label_field else LABEL_FIELDS
        field = next((name for name in candidates if name in cloud.fields), None)
        if field is None:
            raise FormatError(path, f"has no per-point {' or '.join(repr(c) for c in candidates)} field "
                                    f"(its fields: {', '.join(cloud.fields) or 'none'})")
        values = cloud.fields[field]
        if values.ndim != 1 or not (np.issubdtype(values.dtype, np.integer)
                                    or np.array_equal(values, np.round(values))):
            raise FormatError(path, f"its {field!r} field is not one integer per point")
        return cloud, field

    def read(self, index: int) -> PointCloud:
        path = self.files[index]
        cloud, field = self._read_labelled(path)
        scan = as_scan(cloud, path, self.names[index])
        scan.fields[LABEL_FIELD] = labels_of_codes(cloud.fields[field], self.codes)
        kept = np.isfinite(scan.points).all(axis=1)
        if not self.whole_files:
            x = scan.points[:, 0]
            cut = np.quantile(x[kept], 1 - HOLDOUT_FRACTION)
            kept &= (x >= cut) if self.split == "test" else (x < cut)
        return scan.select(kept)


def as_scan(cloud: PointCloud, path: Path, name: str, *, offset: np.ndarray | None = None,
            intensity_scale: float | None = None) -> PointCloud:
    """A cloud as read, in the scene convention (module doc of :mod:`~.scene_base`), without labels.

    Colours become uint8, intensity is divided by its 99th percentile, and float64 coordinates
    (survey coordinates, UTM) are taken relative to the floor of their smallest finite corner,
    since float32 would lose their centimetres (the crops re-centre them anyway). Points keep
    their order and number, non-finite ones included. ``offset`` (subtracted from float64
    coordinates) and ``intensity_scale`` (the divisor), when given, are the whole scan's for a
    piece of it; a piece may then have no finite point.
    """
    fields = {name: cloud.fields[name] for name in ("colors", "normals", "intensity") if name in cloud.fields}
    if "colors" in fields:
        fields["colors"] = _as_uint8_colours(fields["colors"][:, :3])
    if "intensity" in fields:
        fields["intensity"] = _as_unit_intensity(fields["intensity"], intensity_scale)
    points = cloud.points
    if offset is None:
        finite = np.isfinite(points).all(axis=1)
        if not finite.any():
            raise FormatError(path, "has no points with finite coordinates")
        offset = np.floor(points[finite].min(axis=0))
    if points.dtype == np.float64:
        points = points - offset
    return PointCloud(points.astype(np.float32), fields, None, {"scan": name})


def labels_of_codes(values: np.ndarray, codes: Sequence[int]) -> np.ndarray:
    """``(N,)`` int64: the index of each value in ``codes``, -1 where it is none of them."""
    raw = np.asarray(values).astype(np.int64)
    order = np.argsort(np.asarray(codes, np.int64))
    ordered = np.asarray(codes, np.int64)[order]
    if len(ordered) == 0:
        return np.full(len(raw), -1, np.int64)
    position = np.clip(np.searchsorted(ordered, raw), 0, len(ordered) - 1)
    return np.where(ordered[position] == raw, order[position], -1)


def _as_uint8_colours(colours: np.ndarray) -> np.ndarray:
    if colours.dtype == np.uint8:
        return colours
    top = float(np.max(colours, initial=0))
    scale = 255.0 / (65535.0 if top > 255 else 255.0 if top > 1.0 else 1.0)
    return np.clip(np.asarray(colours, np.float64) * scale, 0, 255).astype(np.uint8)


def _as_unit_intensity(intensity: np.ndarray, top: float | None = None) -> np.ndarray:
    """Intensity in about [0, 1]: divided by its 99th percentile (LAS stores 0..65535, KITTI 0..1),
    or by ``top`` when given."""
    values = np.asarray(intensity, np.float64)
    if top is None:
        top = np.percentile(values, 99) if len(values) else 1.0
    return (values / (top if top > 0 else 1.0)).astype(np.float32)
