"""Which scene dataset a DATA argument is: :func:`open_scenes`.

One or more paths name the data, as ``pointfield segment train DATA...`` takes them. A single
folder in one of the public layouts is read in that layout (S3DIS, ScanNet v2, SemanticKITTI);
anything else (labelled files, folders of them) is :class:`~.labelled.LabelledClouds`. See
:mod:`~.scene_base` for the convention every scan is converted into.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from pointfield.clouds.datasets.labelled import LabelledClouds
from pointfield.clouds.datasets.s3dis import S3DIS, is_s3dis
from pointfield.clouds.datasets.scannet import ScanNet, is_scannet
from pointfield.clouds.datasets.scene_base import SceneDataset
from pointfield.clouds.datasets.semantickitti import SemanticKITTI, is_semantickitti

SCENE_LAYOUTS = ("s3dis", "scannet", "semantickitti", "labelled")


def scene_layout(paths: Sequence[str | os.PathLike[str]]) -> str:
    """The layout of DATA: ``"s3dis"``, ``"scannet"``, ``"semantickitti"`` or ``"labelled"``."""
    if len(paths) == 1 and Path(paths[0]).is_dir():
        root = Path(paths[0])
        for name, test in (("s3dis", is_s3dis), ("scannet", is_scannet), ("semantickitti", is_semantickitti)):
            if test(root):
                return name
    return "labelled"


def open_scenes(
    paths: Sequence[str | os.PathLike[str]],
    split: str,
    *,
    label_field: str | None = None,
    classes: Sequence[str] | Mapping | None = None,
    codes: Sequence[int] | None = None,
    test_area: int = 5,
) -> SceneDataset:
    """The ``split`` of the scene data at ``paths`` (see the module doc).

    ``label_field``, ``classes`` and ``codes`` are for labelled files (:class:`LabelledClouds`);
    ``test_area`` is S3DIS's held-out area.
    """
    layout = scene_layout(paths)
    if layout == "s3dis":
        return S3DIS(paths[0], split, test_area=test_area)
    if layout == "scannet":
        return ScanNet(paths[0], split)
    if layout == "semantickitti":
        return SemanticKITTI(paths[0], split)
    return LabelledClouds(paths, split, label_field=label_field, classes=classes, codes=codes)
