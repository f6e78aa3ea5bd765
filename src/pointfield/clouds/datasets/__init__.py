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
==================================================  =========================================================================

:class:`CloudCollate` turns a list of samples into a :class:`CloudBatch`: points padded to the
largest cloud, with a mask, so clouds of different sizes batch together.

Modules: ``base`` (the dataset contract), ``folder`` (:class:`CloudFolder` and its layouts),
``modelnet`` (:class:`ModelNet`'s three distributions), ``loading`` (one file to one clean
cloud) and ``cache`` (where sampled meshes are kept), ``collate`` (samples to batches).
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
from pointfield.clouds.datasets.loading import DEFAULT_MESH_POINTS
from pointfield.clouds.datasets.modelnet import (
    MODELNET_TXT_POINTS,
    ModelNet,
    modelnet_source,
)

__all__ = [
    "DEFAULT_MESH_POINTS",
    "MODELNET_TXT_POINTS",
    "PART_LABEL_FIELD",
    "SPLITS",
    "CloudBatch",
    "CloudCollate",
    "CloudDataset",
    "CloudFolder",
    "InMemoryClouds",
    "ModelNet",
    "default_cache_dir",
    "modelnet_source",
]
