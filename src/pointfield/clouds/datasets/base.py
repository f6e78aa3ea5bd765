"""The dataset contract: what every point-cloud dataset yields and which attributes it sets.

:class:`CloudDataset` is the base (``load(i)`` gives the raw sample, ``dataset[i]`` the
transformed one, with augmentation seeded per sample and epoch); :class:`InMemoryClouds` is a
dataset whose clouds were all read when it was built, as :class:`CloudFolder` and
:class:`ModelNet` are.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from pointfield.clouds.cloud import PointCloud

SPLITS = ("train", "test")
# The integer per-point field that carries part labels for segmentation.
PART_LABEL_FIELD = "label"


class CloudDataset(torch.utils.data.Dataset):
    """Base of the datasets: ``load(i)`` gives the raw sample, ``dataset[i]`` the transformed one.

    ``transform(cloud, rng)`` receives a generator seeded with ``(seed, epoch, i)``: augmentation
    is reproducible, independent of DataLoader workers, and new each epoch once the training
    loop calls :meth:`set_epoch`.

    Attributes every dataset sets: ``classes`` (class names, index = label), ``parts`` (names of
    the per-point labels, or None when clouds carry none) and ``root`` (where the data came
    from, or None). Part datasets whose categories own fixed parts (ShapeNetPart, the synthetic
    shapes) also set ``category_parts``: for each class, the part labels its shapes can have,
    which the per-shape scores need (:func:`pointfield.metrics.shape_part_iou`).
    """

    classes: list[str]
    parts: list[str] | None = None
    category_parts: list[tuple[int, ...]] | None = None
    root: Path | None = None

    def __init__(self, transform: Callable | None = None, seed: int = 0):
        self.transform = transform
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def load(self, index: int) -> tuple[PointCloud, int]:
        raise NotImplementedError

    def class_labels(self) -> np.ndarray:
        """``(len(self),)`` class index of every sample, without loading or transforming them."""
        raise NotImplementedError

    def __getitem__(self, index: int) -> tuple[PointCloud, int]:
        cloud, label = self.load(index)
        if self.transform is not None:
            cloud = self.transform(cloud, np.random.default_rng([self.seed, self.epoch, index]))
        # Where the sample came from, so that a batch that cannot be made names its file.
        return dataclasses.replace(cloud, metadata={**cloud.metadata, "source": self.source_of(index)}), label

    def source_of(self, index: int) -> str:
        """The file sample ``index`` was read from (``files[index]``), else ``"sample <index>"``."""
        files = getattr(self, "files", None)
        return str(files[index]) if files is not None and index < len(files) else f"sample {index}"

    def with_transform(self, transform: Callable | None) -> CloudDataset:
        """A shallow copy of this dataset (same loaded clouds) with another transform."""
        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.transform = transform
        return copy

    def describe(self) -> str:
        return f"{type(self).__name__}: {len(self)} clouds, {len(self.classes)} classes"


class InMemoryClouds(CloudDataset):
    """A dataset whose clouds were all loaded when it was built: ``clouds``, ``labels``, ``files``."""

    def __init__(self, transform: Callable | None = None, seed: int = 0):
        super().__init__(transform, seed)
        self.clouds: list[PointCloud] = []
        self.labels: list[int] = []
        self.files: list[Path] = []
        self.skipped: list[tuple[Path, str]] = []
        self.held_out = False

    def __len__(self) -> int:
        return len(self.clouds)

    def load(self, index: int) -> tuple[PointCloud, int]:
        return self.clouds[index], self.labels[index]

    def class_labels(self) -> np.ndarray:
        return np.asarray(self.labels, np.int64)
