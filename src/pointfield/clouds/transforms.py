"""Small composable transforms of a :class:`PointCloud`, augmentations included.

In the manner of PyTorch Geometric: one class per transform, its settings in the constructor and
in its ``repr``, composed with :class:`Compose`::

    >>> Compose([NormaliseScale(), SamplePoints(1024), RandomJitter(0.01, clip=0.05)])
    Compose([NormaliseScale(), SamplePoints(1024), RandomJitter(sigma=0.01, clip=0.05)])

Every transform returns a new cloud and leaves its input alone. Per-point fields follow their
points (a part-label field survives sampling and dropout); transforms that turn or stretch the
points turn ``normals`` with them.

Randomness is seedable two ways. A random transform built with ``seed=`` draws from its own
generator, so a script that applies it in order is reproducible. A caller can also pass a
``numpy.random.Generator`` at call time, ``transform(cloud, rng)``, and then that generator is
used: the datasets do this with one generator per (seed, epoch, sample), so augmentation does
not depend on the number of DataLoader workers or on whether a run was resumed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pointfield.clouds import ops
from pointfield.clouds.cloud import PointCloud

AXES = {"x": 0, "y": 1, "z": 2}


class Transform:
    """Base class: ``transform(cloud, rng=None) -> cloud``."""

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class RandomTransform(Transform):
    """A transform that draws random numbers: from ``rng`` when given, else its own generator."""

    def __init__(self, seed: int | None = None):
        self.seed = seed
        self._generator = np.random.default_rng(seed)

    def generator(self, rng: np.random.Generator | None) -> np.random.Generator:
        return rng if rng is not None else self._generator


class Compose(Transform):
    """Apply transforms in order, passing the same generator to each."""

    def __init__(self, transforms: Sequence[Transform]):
        self.transforms = list(transforms)

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        for transform in self.transforms:
            cloud = transform(cloud, rng)
        return cloud

    def __repr__(self) -> str:
        return f"Compose([{', '.join(map(repr, self.transforms))}])"


class DropNonFinite(Transform):
    """Remove points with a NaN or infinite coordinate (invalid returns of organised sensors)."""

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        finite = ops.finite_rows(cloud.points)
        return cloud if finite.all() else cloud.select(finite)


class Centre(Transform):
    """Translate the cloud so its mean is the origin."""

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return _replace_points(cloud, ops.centre(cloud.points))


class NormaliseScale(Transform):
    """Centre the cloud and scale it into the unit sphere; float32 points."""

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return _replace_points(cloud, ops.normalise_to_unit_sphere(cloud.points))


class SamplePoints(RandomTransform):
    """Keep ``size`` random points; a smaller cloud is padded by repeating random points."""

    def __init__(self, size: int, seed: int | None = None):
        super().__init__(seed)
        self.size = size

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return cloud.select(ops.random_sample(len(cloud), self.size, self.generator(rng)))

    def __repr__(self) -> str:
        return f"SamplePoints({self.size})"


class CanonicalSample(Transform):
    """Keep ``size`` points chosen by their coordinates alone (same subset in any point order)."""

    def __init__(self, size: int):
        self.size = size

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return cloud.select(ops.canonical_sample(cloud.points, self.size))

    def __repr__(self) -> str:
        return f"CanonicalSample({self.size})"


class FarthestPointSample(Transform):
    """Keep a farthest point sample of ``size`` points (fpsample), starting farthest from the centre."""

    def __init__(self, size: int):
        self.size = size

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return cloud.select(ops.farthest_point_sample(cloud.points, self.size))

    def __repr__(self) -> str:
        return f"FarthestPointSample({self.size})"


class VoxelDownsample(Transform):
    """Replace the points in each cube of side ``voxel_size`` by their mean."""

    def __init__(self, voxel_size: float):
        self.voxel_size = voxel_size

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return ops.voxel_downsample(cloud, self.voxel_size)

    def __repr__(self) -> str:
        return f"VoxelDownsample({self.voxel_size})"


class EstimateNormals(Transform):
    """Add (or replace) ``normals`` by PCA over the ``neighbours`` nearest points."""

    def __init__(self, neighbours: int = 16):
        self.neighbours = neighbours

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        normals = ops.estimate_normals(cloud.points, self.neighbours)
        fields = {**cloud.fields, "normals": normals}
        return PointCloud(cloud.points, fields, cloud.shape, dict(cloud.metadata))

    def __repr__(self) -> str:
        return f"EstimateNormals(neighbours={self.neighbours})"


class RandomRotate(RandomTransform):
    """Rotate by a random angle in ``[-degrees, degrees]`` about ``axis``, or uniformly if None.

    ``axis="z"`` (the default) turns a shape about the up axis of z-up data, the usual
    augmentation for ModelNet; ``axis=None`` draws a rotation uniformly from all of SO(3)
    (a random unit quaternion) and ignores ``degrees``.
    """

    def __init__(self, degrees: float = 180.0, axis: str | None = "z", seed: int | None = None):
        super().__init__(seed)
        if axis is not None and axis not in AXES:
            raise ValueError(f"axis must be one of x, y, z or None, got {axis!r}")
        self.degrees = degrees
        self.axis = axis

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        generator = self.generator(rng)
        if self.axis is None:
            rotation = _uniform_rotation(generator)
        else:
            angle = np.deg2rad(generator.uniform(-self.degrees, self.degrees))
            rotation = _axis_rotation(AXES[self.axis], angle)
        return _linear_map(cloud, rotation)

    def __repr__(self) -> str:
        if self.axis is None:
            return "RandomRotate(axis=None)"
        return f"RandomRotate(degrees={self.degrees:g}, axis={self.axis!r})"


class RandomJitter(RandomTransform):
    """Add Gaussian noise of standard deviation ``sigma`` to every coordinate, clipped to ``clip``."""

    def __init__(self, sigma: float = 0.01, clip: float | None = 0.05, seed: int | None = None):
        super().__init__(seed)
        self.sigma = sigma
        self.clip = clip

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        noise = self.generator(rng).normal(0.0, self.sigma, cloud.points.shape)
        if self.clip is not None:
            noise = np.clip(noise, -self.clip, self.clip)
        return _replace_points(cloud, (cloud.points + noise).astype(cloud.points.dtype))

    def __repr__(self) -> str:
        return f"RandomJitter(sigma={self.sigma:g}, clip={self.clip!r})"


class RandomScale(RandomTransform):
    """Multiply coordinates by a factor drawn uniformly from ``[low, high]``.

    One factor per axis when ``anisotropic`` (a shape is stretched, as PointNet++ augments),
    else one for all three.
    """

    def __init__(
        self, low: float = 0.8, high: float = 1.25, anisotropic: bool = True,
        seed: int | None = None,
    ):
        super().__init__(seed)
        if not 0 < low <= high:
            raise ValueError(f"need 0 < low <= high, got {low}, {high}")
        self.low, self.high, self.anisotropic = low, high, anisotropic

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        factors = self.generator(rng).uniform(self.low, self.high, 3 if self.anisotropic else 1)
        return _linear_map(cloud, np.diag(np.broadcast_to(factors, 3)))

    def __repr__(self) -> str:
        return f"RandomScale(low={self.low:g}, high={self.high:g}, anisotropic={self.anisotropic})"


class RandomShift(RandomTransform):
    """Translate the whole cloud by a vector uniform in ``[-max_shift, max_shift]³``."""

    def __init__(self, max_shift: float = 0.1, seed: int | None = None):
        super().__init__(seed)
        self.max_shift = max_shift

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        shift = self.generator(rng).uniform(-self.max_shift, self.max_shift, 3)
        return _replace_points(cloud, (cloud.points + shift).astype(cloud.points.dtype))

    def __repr__(self) -> str:
        return f"RandomShift(max_shift={self.max_shift:g})"


class RandomDropout(RandomTransform):
    """Drop a random fraction, up to ``max_ratio``, of the points, keeping the point count.

    PointNet++'s "random input dropout": the fraction is drawn uniformly from
    ``[0, max_ratio]`` per cloud, and each dropped point (and its fields) is replaced by a copy
    of the first kept point, so batches stay rectangular and a max-pool sees only kept points.
    """

    def __init__(self, max_ratio: float = 0.875, seed: int | None = None):
        super().__init__(seed)
        if not 0 <= max_ratio < 1:
            raise ValueError(f"max_ratio must be in [0, 1), got {max_ratio}")
        self.max_ratio = max_ratio

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        generator = self.generator(rng)
        ratio = generator.uniform(0, self.max_ratio)
        dropped = generator.random(len(cloud)) < ratio
        if dropped.all() or not dropped.any():
            return cloud
        index = np.arange(len(cloud))
        index[dropped] = np.flatnonzero(~dropped)[0]
        return cloud.select(index)

    def __repr__(self) -> str:
        return f"RandomDropout(max_ratio={self.max_ratio:g})"


class Shuffle(RandomTransform):
    """Put the points (and their fields) in a random order."""

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return cloud.select(self.generator(rng).permutation(len(cloud)))


class ScaleBy(Transform):
    """Multiply coordinates by a fixed ``factor`` (a scene crop of radius r into the unit ball: 1 / r)."""

    def __init__(self, factor: float):
        if not factor > 0:
            raise ValueError(f"factor must be positive, got {factor}")
        self.factor = factor

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        return _replace_points(cloud, (cloud.points * self.factor).astype(cloud.points.dtype))

    def __repr__(self) -> str:
        return f"ScaleBy(factor={self.factor:g})"


class ColourJitter(RandomTransform):
    """Add Gaussian noise of standard deviation ``sigma`` to each channel of the float colour
    ``field`` (values in [0, 1]), clipped back to [0, 1]: Pointcept's ``ChromaticJitter``."""

    def __init__(self, sigma: float = 0.05, field: str = "colour", seed: int | None = None):
        super().__init__(seed)
        self.sigma, self.field = sigma, field

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        if self.field not in cloud.fields:
            return cloud
        colour = cloud.fields[self.field]
        noisy = np.clip(colour + self.generator(rng).normal(0.0, self.sigma, colour.shape), 0.0, 1.0)
        return PointCloud(cloud.points, {**cloud.fields, self.field: noisy.astype(colour.dtype)}, cloud.shape,
                          dict(cloud.metadata))

    def __repr__(self) -> str:
        return f"ColourJitter(sigma={self.sigma:g}, field={self.field!r})"


class ColourDrop(RandomTransform):
    """With probability ``probability``, set the whole cloud's colour ``field`` to 0, so that a model
    learns shape as well as colour: Pointcept's ``RandomColorDrop``."""

    def __init__(self, probability: float = 0.2, field: str = "colour", seed: int | None = None):
        super().__init__(seed)
        if not 0 <= probability <= 1:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability, self.field = probability, field

    def __call__(self, cloud: PointCloud, rng: np.random.Generator | None = None) -> PointCloud:
        if self.field not in cloud.fields or self.generator(rng).random() >= self.probability:
            return cloud
        dropped = np.zeros_like(cloud.fields[self.field])
        return PointCloud(cloud.points, {**cloud.fields, self.field: dropped}, cloud.shape, dict(cloud.metadata))

    def __repr__(self) -> str:
        return f"ColourDrop(probability={self.probability:g}, field={self.field!r})"


def _replace_points(cloud: PointCloud, points: np.ndarray) -> PointCloud:
    return PointCloud(points, dict(cloud.fields), cloud.shape, dict(cloud.metadata))


def _linear_map(cloud: PointCloud, matrix: np.ndarray) -> PointCloud:
    """Apply ``p -> A p`` to the points and ``n -> A^-T n`` (renormalised) to the normals.

    Normals transform by the inverse transpose so they stay perpendicular to the surface; for
    a rotation that is the rotation itself.
    """
    points = (cloud.points.astype(np.float64) @ matrix.T).astype(cloud.points.dtype)
    fields = dict(cloud.fields)
    if "normals" in fields:
        normals = fields["normals"].astype(np.float64) @ np.linalg.inv(matrix)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        fields["normals"] = (normals / np.maximum(length, 1e-12)).astype(fields["normals"].dtype)
    return PointCloud(points, fields, cloud.shape, dict(cloud.metadata))


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    """The 3x3 matrix turning by ``angle`` radians about coordinate axis 0, 1 or 2 (right hand)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [a for a in range(3) if a != axis]
    rotation = np.eye(3)
    rotation[i, i], rotation[i, j], rotation[j, i], rotation[j, j] = c, -s, s, c
    return rotation


def _uniform_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation uniform over SO(3): the matrix of a normalised 4-D Gaussian quaternion."""
    quaternion = rng.standard_normal(4)
    w, x, y, z = quaternion / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
