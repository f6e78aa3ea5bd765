"""Labelled scenes, whole: the contract of every scene-segmentation dataset, and how DATA is recognised.

A scene dataset lists the scans of one split and reads them one at a time, each converted at
the edge into the one convention used inside: a :class:`PointCloud`, z up, in metres, whose
int64 field ``label`` is an index into ``dataset.classes`` (-1 for points the dataset leaves
unlabelled, which the loss and the scores ignore), with ``colors`` (N, 3) uint8, ``intensity``
(N,) float32 in about [0, 1] and ``normals`` (N, 3) where the data has them.

==============================================  ============================================
DATA                                            read by
==============================================  ============================================
``Stanford3dDataset_v1.2*`` (``Area_N/``)       :class:`~.s3dis.S3DIS`
ScanNet v2 (``scans/sceneXXXX_XX/``)            :class:`~.scannet.ScanNet`
SemanticKITTI (``sequences/NN/velodyne``)       :class:`~.semantickitti.SemanticKITTI`
labelled clouds, any format pointfield reads    :class:`~.labelled.LabelledClouds`
==============================================  ============================================

:func:`~.scenes.open_scenes` recognises which one a DATA argument is. ShapeNetPart is an object
dataset (:class:`~.shapenetpart.ShapeNetPart`), trained as the shapes are.
"""

from __future__ import annotations

from pathlib import Path

from pointfield.clouds.cloud import PointCloud

SCENE_SPLITS = ("train", "test")
LABEL_FIELD = "label"


class SceneDataset:
    """The scans of one split: ``len(dataset)``, ``dataset.read(i)`` and ``dataset.names[i]``.

    Attributes: ``classes`` (class names, index = label), ``names`` (one per scan, e.g.
    ``Area_5/office_1``), ``root`` (the folder, or None) and ``split``.
    """

    classes: list[str]
    names: list[str]
    root: Path | None = None
    split: str | None = None
    codes: list[int] | None = None
    """The value of each class in the files, where it is not its index (labelled files)."""

    def class_codes(self) -> list[int]:
        """Class i's value in the files: ``codes[i]``, or i."""
        return list(self.codes) if self.codes is not None else list(range(len(self.classes)))

    def __len__(self) -> int:
        return len(self.names)

    def read(self, index: int) -> PointCloud:
        """Scan ``index`` as a labelled cloud (see the module doc)."""
        raise NotImplementedError

    def describe(self) -> str:
        where = f"{self.root} " if self.root is not None else ""
        return f"{type(self).__name__} {where}({self.split}): {len(self)} scans, {len(self.classes)} classes"


def check_split(split: str) -> None:
    if split not in SCENE_SPLITS:
        raise ValueError(f"split must be 'train' or 'test', got {split!r}")
