"""SemanticKITTI (Behley et al., ICCV 2019), read from KITTI odometry's folder with the labels unpacked into it.

Layout (``dataset/`` of the odometry download, or the folder holding ``sequences/``)::

    root/semantic-kitti.yaml                   optional: the label configuration of semantic-kitti-api
    root/sequences/00/velodyne/000000.bin      a sweep: float32 records x y z reflectance
    root/sequences/00/labels/000000.label      uint32 per point: instance << 16 | semantic label
    ...

Each sweep is one scan. The lower 16 bits of a ``.label`` value are the raw semantic label
(the upper 16 the instance); ``learning_map`` folds the 28 raw labels into the 19 classes of
the benchmark plus 0, "unlabeled", which is ignored. The map, the class names
(``labels[learning_map_inv[i]]``) and the splits (``split: train / valid``) come from
``semantic-kitti.yaml`` when ``root`` holds it, else from the copy of that file's values
below (semantic-kitti-api, ``config/semantic-kitti.yaml``): training sequences 00-07, 09, 10
and validation 08, the usual test split since the benchmark's test labels are hidden.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.scene_base import LABEL_FIELD, SceneDataset, check_split
from pointfield.clouds.formats import read
from pointfield.errors import FormatError, PointfieldError

CONFIG_FILE = "semantic-kitti.yaml"
# semantic-kitti.yaml's learning_map (raw label -> 0..19) and the names of 1..19.
LEARNING_MAP = {
    0: 0, 1: 0, 10: 1, 11: 2, 13: 5, 15: 3, 16: 5, 18: 4, 20: 5, 30: 6, 31: 7, 32: 8, 40: 9, 44: 10, 48: 11,
    49: 12, 50: 13, 51: 14, 52: 0, 60: 9, 70: 15, 71: 16, 72: 17, 80: 18, 81: 19, 99: 0, 252: 1, 253: 7,
    254: 6, 255: 8, 256: 5, 257: 5, 258: 4, 259: 5,
}
CLASS_NAMES = ("car", "bicycle", "motorcycle", "truck", "other-vehicle", "person", "bicyclist", "motorcyclist",
               "road", "parking", "sidewalk", "other-ground", "building", "fence", "vegetation", "trunk",
               "terrain", "pole", "traffic-sign")
SPLITS = {"train": (0, 1, 2, 3, 4, 5, 6, 7, 9, 10), "test": (8,)}
SEQUENCE = re.compile(r"^\d{2}$")


def sequences_folder(root: Path) -> Path | None:
    for folder in (root / "sequences", root / "dataset" / "sequences"):
        if folder.is_dir() and any(SEQUENCE.match(p.name) and (p / "velodyne").is_dir() for p in folder.iterdir()):
            return folder
    return None


def is_semantickitti(root: Path) -> bool:
    return root.is_dir() and sequences_folder(root) is not None


def read_config(path: Path) -> tuple[dict[int, int], list[str], dict[str, tuple[int, ...]]]:
    """``(learning_map, class names of 1..K, {"train": sequences, "test": sequences})`` from the YAML."""
    try:
        config: Any = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise FormatError(path, f"not valid YAML: {error}".replace("\n", " ")) from None
    try:
        learning_map = {int(k): int(v) for k, v in config["learning_map"].items()}
        inverse = {int(k): int(v) for k, v in config["learning_map_inv"].items()}
        labels = {int(k): str(v) for k, v in config["labels"].items()}
        names = [labels[inverse[i]] for i in range(1, max(inverse) + 1)]
        splits = {"train": tuple(int(s) for s in config["split"]["train"]),
                  "test": tuple(int(s) for s in config["split"]["valid"])}
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise FormatError(path, f"expected learning_map, learning_map_inv, labels and split.train / "
                                f"split.valid as in semantic-kitti-api's file ({type(error).__name__}: {error})") from None
    return learning_map, names, splits


class SemanticKITTI(SceneDataset):
    """The labelled sweeps of the sequences of ``split`` (``"test"``: the validation sequence 08)."""

    def __init__(self, root: str | os.PathLike[str], split: str = "train"):
        check_split(split)
        self.root, self.split = Path(root), split
        sequences = sequences_folder(self.root)
        if sequences is None:
            raise PointfieldError(f"{self.root}: not a SemanticKITTI folder (expected sequences/NN/velodyne/)")
        config = self.root / CONFIG_FILE
        if config.is_file():
            learning_map, self.classes, splits = read_config(config)
        else:
            learning_map, self.classes, splits = LEARNING_MAP, list(CLASS_NAMES), SPLITS
        # Raw label -> class index, -1 for "unlabeled" (learned 0) and for raw labels the map lacks.
        self.label_of_raw = np.full(1 << 16, -1, np.int64)
        for raw, learned in learning_map.items():
            if 0 <= raw < 1 << 16:
                self.label_of_raw[raw] = learned - 1
        self.sweeps: list[tuple[Path, Path]] = []
        for folder in sorted(p for p in sequences.iterdir() if SEQUENCE.match(p.name)):
            if int(folder.name) not in splits[split] or not (folder / "labels").is_dir():
                continue  # the test sequences 11-21 come without labels
            for scan in sorted((folder / "velodyne").glob("*.bin")):
                self.sweeps.append((scan, folder / "labels" / f"{scan.stem}.label"))
        self.names = [f"{scan.parent.parent.name}/{scan.stem}" for scan, _ in self.sweeps]

    def read(self, index: int) -> PointCloud:
        scan, label_path = self.sweeps[index]
        cloud = read(scan, format="velodyne", columns=4)
        if not label_path.is_file():
            raise FormatError(label_path, f"missing: every sweep needs its .label file beside velodyne/{scan.name}")
        size = label_path.stat().st_size
        if size != 4 * len(cloud):
            raise FormatError(label_path, f"{size} bytes, expected 4 per point of {scan.name} ({4 * len(cloud)})")
        raw = np.fromfile(label_path, dtype="<u4") & 0xFFFF
        fields = {LABEL_FIELD: self.label_of_raw[raw], "intensity": cloud.fields["intensity"].astype(np.float32)}
        return PointCloud(cloud.points.astype(np.float32), fields, None, {"scan": self.names[index]})
