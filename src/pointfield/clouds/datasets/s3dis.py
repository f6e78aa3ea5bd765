"""S3DIS (Armeni et al., CVPR 2016), read from the folder its authors distribute.

Layout of ``Stanford3dDataset_v1.2_Aligned_Version`` (or ``_v1.2``)::

    root/Area_1/conferenceRoom_1/conferenceRoom_1.txt     the whole room (not read here)
    root/Area_1/conferenceRoom_1/Annotations/chair_1.txt   one object: rows "x y z r g b"
    root/Area_1/conferenceRoom_1/Annotations/wall_3.txt
    ...
    root/Area_6/...

Each room is one scan: the points of all its ``Annotations/<class>_<k>.txt`` files, labelled by
the class in the file's name. The 13 classes are :data:`S3DIS_CLASSES`; a file of another name
(``stairs_1.txt`` in Area 2 and 5) is clutter, as the reference preprocessing scripts of
PointNet and Pointcept count it. Colours are 0..255 integers. The standard protocol holds out
Area 5 (``test_area=5``): the test split is its rooms, the training split every other area's.
A row that is not six numbers (one line of ``Area_5/office_19/Annotations/ceiling_1.txt`` in
the distributed files holds a stray control byte) is a :class:`FormatError` naming the file and
the line, to be fixed by hand as the reference scripts do.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.scene_base import LABEL_FIELD, SceneDataset, check_split
from pointfield.clouds.formats import read
from pointfield.errors import FormatError, PointfieldError

S3DIS_CLASSES = ("ceiling", "floor", "wall", "beam", "column", "window", "door", "table", "chair", "sofa",
                 "bookcase", "board", "clutter")
AREA = re.compile(r"^Area_(\d+)$")
COLUMNS = "x y z red green blue"


def is_s3dis(root: Path) -> bool:
    """True when ``root`` holds ``Area_N`` folders."""
    return root.is_dir() and any(AREA.match(p.name) and p.is_dir() for p in root.iterdir())


class S3DIS(SceneDataset):
    """The rooms of S3DIS: those of ``test_area`` for ``split="test"``, of every other area for ``"train"``."""

    def __init__(self, root: str | os.PathLike[str], split: str = "train", *, test_area: int = 5):
        check_split(split)
        self.classes = list(S3DIS_CLASSES)
        self.root, self.split, self.test_area = Path(root), split, test_area
        if not is_s3dis(self.root):
            raise PointfieldError(f"{self.root}: not an S3DIS folder (expected Area_1 ... Area_6 folders in it)")
        areas = sorted((int(AREA.match(p.name).group(1)), p) for p in self.root.iterdir()
                       if p.is_dir() and AREA.match(p.name))
        if test_area not in [number for number, _ in areas]:
            raise PointfieldError(f"{self.root}: no Area_{test_area} folder to hold out as the test area")
        self.rooms: list[Path] = []
        for number, area in areas:
            if (number == test_area) == (split == "test"):
                self.rooms += sorted(p for p in area.iterdir() if p.is_dir() and not p.name.startswith("."))
        self.names = [f"{room.parent.name}/{room.name}" for room in self.rooms]

    def read(self, index: int) -> PointCloud:
        room = self.rooms[index]
        annotations = room / "Annotations"
        files = sorted(annotations.glob("*.txt")) if annotations.is_dir() else []
        if not files:
            raise FormatError(annotations, "no <class>_<k>.txt annotation files (expected e.g. chair_1.txt)")
        points, colours, labels = [], [], []
        for path in files:
            name = path.stem.rsplit("_", 1)[0]
            label = self.classes.index(name) if name in self.classes else self.classes.index("clutter")
            part = read(path, format="text", columns=COLUMNS)
            if len(part) == 0:
                continue
            points.append(part.points.astype(np.float32))
            colours.append(np.clip(part.fields["colors"], 0, 255).astype(np.uint8))
            labels.append(np.full(len(part), label, np.int64))
        if not points:
            raise FormatError(annotations, "every annotation file is empty")
        fields = {"colors": np.concatenate(colours), LABEL_FIELD: np.concatenate(labels)}
        return PointCloud(np.concatenate(points), fields, None, {"scan": self.names[index]})
