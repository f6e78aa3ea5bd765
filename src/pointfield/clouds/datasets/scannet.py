"""ScanNet v2 (Dai et al., CVPR 2017), read from the folder its download script writes.

Layout::

    root/scannetv2-labels.combined.tsv                  label table (tab-separated, with a header)
    root/scannetv2_train.txt, root/scannetv2_val.txt    the benchmark's splits, one scene per line
    root/scans/scene0000_00/scene0000_00_vh_clean_2.ply          the mesh: vertices x y z red green blue
    root/scans/scene0000_00/scene0000_00_vh_clean_2.labels.ply   the same vertices, property ``label``
    ...

Each scene is one scan: the vertices of its ``_vh_clean_2.ply`` mesh with their colours, each
labelled by the ``label`` property of the same vertex in ``_vh_clean_2.labels.ply``, an NYU40
class id. The semantic-segmentation benchmark keeps 20 of the 40 (:data:`BENCHMARK_IDS`, from
ScanNet's ``Tasks/Benchmark`` scripts) and ignores the rest; their names are the
``nyu40class`` of those ids in the label table's ``nyu40id`` / ``nyu40class`` columns. The test
split is ``scannetv2_val.txt`` (the benchmark's test labels are not public) and the training
split ``scannetv2_train.txt``; without those files, the last fifth of the scenes by name is
held out. The scans folder may also be ``root`` itself.
"""

from __future__ import annotations

import csv
import math
import os
import re
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.scene_base import LABEL_FIELD, SceneDataset, check_split
from pointfield.clouds.formats import read
from pointfield.errors import FormatError, PointfieldError

LABEL_TABLE = "scannetv2-labels.combined.tsv"
SPLIT_FILES = {"train": "scannetv2_train.txt", "test": "scannetv2_val.txt"}
# NYU40 ids of the 20 benchmark classes, in the benchmark's order.
BENCHMARK_IDS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 16, 24, 28, 33, 34, 36, 39)
SCENE = re.compile(r"^scene\d{4}_\d{2}$")


def scans_folder(root: Path) -> Path | None:
    """The folder holding the ``sceneXXXX_XX`` folders: ``root/scans`` or ``root``, else None."""
    for folder in (root / "scans", root):
        if folder.is_dir() and any(SCENE.match(p.name) and p.is_dir() for p in folder.iterdir()):
            return folder
    return None


def is_scannet(root: Path) -> bool:
    return root.is_dir() and (root / LABEL_TABLE).is_file() and scans_folder(root) is not None


def benchmark_classes(table: Path) -> list[str]:
    """The 20 benchmark class names, read from the label table's ``nyu40id`` and ``nyu40class`` columns."""
    if not table.is_file():
        raise FormatError(table, "missing: the ScanNet label table is needed for the class names")
    names: dict[int, str] = {}
    with table.open(newline="", encoding="utf-8") as stream:
        reader = csv.DictReader(stream, delimiter="\t")
        missing = {"nyu40id", "nyu40class"} - set(reader.fieldnames or ())
        if missing:
            raise FormatError(table, f"line 1: no column {' or '.join(sorted(missing))} in the header")
        for line, row in enumerate(reader, start=2):
            try:
                names.setdefault(int(row["nyu40id"]), row["nyu40class"])
            except (TypeError, ValueError):
                raise FormatError(table, f"line {line}: nyu40id {row['nyu40id']!r} is not a number") from None
    absent = [i for i in BENCHMARK_IDS if i not in names]
    if absent:
        raise FormatError(table, f"no row for the benchmark's NYU40 ids {absent}")
    return [names[i] for i in BENCHMARK_IDS]


class ScanNet(SceneDataset):
    """The scenes of ScanNet v2's ``split`` (``"test"``: the benchmark's validation scenes)."""

    def __init__(self, root: str | os.PathLike[str], split: str = "train"):
        check_split(split)
        self.root, self.split = Path(root), split
        scans = scans_folder(self.root)
        if scans is None:
            raise PointfieldError(f"{self.root}: not a ScanNet folder (expected scans/sceneXXXX_XX folders)")
        self.classes = benchmark_classes(self.root / LABEL_TABLE)
        scenes = sorted(p.name for p in scans.iterdir() if p.is_dir() and SCENE.match(p.name))
        listed = self.root / SPLIT_FILES[split]
        if (self.root / SPLIT_FILES["test"]).is_file():
            if not listed.is_file():
                raise FormatError(listed, f"missing: {SPLIT_FILES['test']} is there, so the {split} list must be")
            wanted = [line.strip() for line in listed.read_text().splitlines() if line.strip()]
            self.names = [name for name in wanted if name in scenes]
        else:
            held = math.ceil(len(scenes) / 5) if len(scenes) >= 2 else 0
            self.names = scenes[len(scenes) - held:] if split == "test" else scenes[: len(scenes) - held]
        self.scans = scans
        self.label_of_id = np.full(max(BENCHMARK_IDS) + 1, -1, np.int64)
        self.label_of_id[list(BENCHMARK_IDS)] = np.arange(len(BENCHMARK_IDS))

    def read(self, index: int) -> PointCloud:
        name = self.names[index]
        mesh_path = self.scans / name / f"{name}_vh_clean_2.ply"
        labels_path = self.scans / name / f"{name}_vh_clean_2.labels.ply"
        for path in (mesh_path, labels_path):
            if not path.is_file():
                raise FormatError(path, "missing (every ScanNet scene needs its mesh and its .labels.ply)")
        mesh, labelled = read(mesh_path), read(labels_path)
        if "label" not in labelled.fields:
            raise FormatError(labels_path, "its vertices have no 'label' property")
        if len(labelled) != len(mesh):
            raise FormatError(labels_path, f"{len(labelled)} vertices, but {mesh_path.name} has {len(mesh)}")
        ids = labelled.fields["label"].astype(np.int64)
        known = (ids >= 0) & (ids < len(self.label_of_id))
        labels = np.where(known, self.label_of_id[np.clip(ids, 0, len(self.label_of_id) - 1)], -1)
        fields = {LABEL_FIELD: labels}
        if "colors" in mesh.fields:
            fields["colors"] = mesh.fields["colors"][:, :3].astype(np.uint8)
        if "normals" in mesh.fields:
            fields["normals"] = mesh.fields["normals"].astype(np.float32)
        return PointCloud(mesh.points.astype(np.float32), fields, None, {"scan": name})
