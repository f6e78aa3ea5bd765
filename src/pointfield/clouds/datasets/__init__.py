"""PyTorch datasets of labelled point clouds, and the collation of clouds into batches.

Every dataset here yields ``(cloud, label)``: a :class:`PointCloud` (after the dataset's
``transform``) and its class index into ``dataset.classes``. Per-point labels, for
segmentation, travel in the cloud as the integer field ``label`` (names in ``dataset.parts``),
so they follow their points through sampling and augmentation.

==================================================  =========================================================================
:class:`CloudFolder`                                a folder of files in any format :func:`pointfield.read` reads, one
                                                    subfolder per class, optional ``train`` / ``test`` subfolders
:class:`ModelNet`                                   ModelNet10 / 40 from raw OFF meshes, ``modelnet40_normal_resampled`` text
                                                    files, or ``ply_hdf5_2048`` HDF5 files
:class:`~pointfield.clouds.shapes.SyntheticShapes`  procedural shapes (built-in default)
:class:`ShapeNetPart`                               ShapeNetPart part segmentation (``..._v0_normal``), 16 categories, 50 parts
==================================================  =========================================================================

Scenes for semantic segmentation are read whole, one scan at a time, by a
:class:`~.scene_base.SceneDataset` in each dataset's own layout: :class:`S3DIS`,
:class:`ScanNet` v2, :class:`SemanticKITTI`, and :class:`LabelledClouds` (labelled files in any
format); :func:`open_scenes` recognises which one a DATA argument is.

:class:`CloudCollate` turns a list of samples into a :class:`CloudBatch`: points padded to the
largest cloud, with a mask, so clouds of different sizes batch together.

Modules: ``base`` (the dataset contract), ``folder`` (:class:`CloudFolder` and its layouts),
``modelnet`` (:class:`ModelNet`'s three distributions), ``shapenetpart``, the scene datasets
(``scene_base``, ``s3dis``, ``scannet``, ``semantickitti``, ``labelled``, ``scenes``),
``loading`` (one file to one clean cloud) and ``cache`` (where sampled meshes are kept), ``collate`` (samples to batches).
"""

from pointfield.clouds.datasets.base import (
    PART_LABEL_FIELD,
    SPLITS,
    CloudDataset,
    InMemoryClouds,
)
from pointfield.clouds.datasets.cache import default_cache_dir
from pointfield.clouds.datasets.collate import CloudBatch, CloudCollate
from pointfield.clouds.datasets.folder import CloudFolder
from pointfield.clouds.datasets.labelled import LabelledClouds
from pointfield.clouds.datasets.loading import DEFAULT_MESH_POINTS
from pointfield.clouds.datasets.modelnet import (
    MODELNET_TXT_POINTS,
    ModelNet,
    modelnet_source,
)
from pointfield.clouds.datasets.s3dis import S3DIS
from pointfield.clouds.datasets.scannet import ScanNet
from pointfield.clouds.datasets.scene_base import SceneDataset
from pointfield.clouds.datasets.scenes import open_scenes, scene_layout
from pointfield.clouds.datasets.semantickitti import SemanticKITTI
from pointfield.clouds.datasets.shapenetpart import ShapeNetPart, is_shapenetpart

__all__ = [
    "DEFAULT_MESH_POINTS",
    "MODELNET_TXT_POINTS",
    "PART_LABEL_FIELD",
    "S3DIS",
    "SPLITS",
    "CloudBatch",
    "CloudCollate",
    "CloudDataset",
    "CloudFolder",
    "InMemoryClouds",
    "LabelledClouds",
    "ModelNet",
    "ScanNet",
    "SceneDataset",
    "SemanticKITTI",
    "ShapeNetPart",
    "default_cache_dir",
    "is_shapenetpart",
    "modelnet_source",
    "open_scenes",
    "scene_layout",
]
