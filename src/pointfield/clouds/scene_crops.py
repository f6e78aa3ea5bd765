"""Scenes cut into crops a point network can take: grid subsampling, class-balanced training crops,
and overlapping windows that cover a whole scan for prediction, with votes.

A scan of millions of points is too big for PointNet++ in one piece, and too irregular: a
depth camera puts thousands of points on the nearest wall and a handful on the far one. So, as
every scene-segmentation recipe does (PointNet++, KPConv, Pointcept):

1. :func:`prepare_scene` keeps one point per cube of side ``grid`` (the points' mean, its
   label that of the cube's first point; :func:`~pointfield.clouds.ops.voxel_downsample`),
   which evens out the density, and computes the per-point input features (:data:`FEATURES`);
2. training draws crops (:class:`SceneCrops`): a ball (``shape="sphere"``) or a vertical
   column of square section (``"block"``, PointNet's S3DIS blocks) of ``radius`` metres around
   a centre point whose class is first drawn uniformly among the classes present, so a class
   with 1 % of the points is at the centre of as many crops as the floor is;
3. prediction covers the whole scan with windows (:func:`cover`), cell by cell of a grid of
   columns ``COVER_CELL_RADII`` radii wide in x y (from x = y = 0): in each cell, the first of its
   points in coordinate order not yet in the core (three quarters of the radius) of one of the
   cell's windows becomes the next centre, until every point of the cell is in some core; a window
   with more than ``points`` points is split into chunks of at most ``points``, each a thinner
   copy of the whole window. :func:`vote` averages each point's class probabilities over every
   window that holds it. A cell's windows depend on its own points alone, and a window's points on
   those within a radius of its centre, so a piece of the scan that holds a cell and everything
   within ``COVER_CELL_RADII + 1`` radii of it gives that cell the windows the whole scan gives it
   (what streamed prediction, :mod:`pointfield.clouds.scene_streaming`, predicts tiles by).

Crops reach the model centred on their centre and divided by the radius, so PointNet++'s
radii (0.2 and 0.4 of the unit ball) are 0.4 m and 0.8 m for a crop of 2 m. Windows, chunks
and batches depend on the coordinates alone, not on the order of the points in the file: a
shuffled scan gets the same labels, each point its own.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import torch
from scipy.spatial import cKDTree

from pointfield.clouds import ops
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.base import CloudDataset
from pointfield.clouds.datasets.collate import CloudCollate
from pointfield.clouds.datasets.scene_base import LABEL_FIELD
from pointfield.clouds.transforms import (
    ColourDrop,
    ColourJitter,
    Compose,
    RandomJitter,
    RandomRotate,
    RandomScale,
    ScaleBy,
)
from pointfield.errors import PointfieldError

# Input features besides xyz and their channels: colour (r, g, b in [0, 1]); intensity (about
# [0, 1]); normals (given, or estimated from 16 neighbours); height above the scan's floor (its
# lowest percentile of z), in metres -- what tells a crop of a floor from one of a ceiling.
FEATURES = {"colour": 3, "intensity": 1, "normals": 3, "height": 1}
CROP_SHAPES = ("sphere", "block")
CORE_FRACTION = 0.75
COVER_CELL_RADII = 2.0
NORMAL_NEIGHBOURS = 16


def default_features(scan: PointCloud) -> list[str]:
    """What a scan offers: colour if it has colours, intensity if it has it, and always height."""
    return [name for name, field in (("colour", "colors"), ("intensity", "intensity")) if field in scan.fields] + [
        "height"]


def prepare_scene(
    scan: PointCloud, grid: float, features: Sequence[str], name: str = "scan", return_inverse: bool = False,
    *, origin: np.ndarray | None = None, floor: float | None = None,
) -> PointCloud | tuple[PointCloud, np.ndarray]:
    """``scan`` subsampled on a grid of ``grid`` metres (0: kept whole), with the feature fields.

    The result has the int64 ``label`` field (when the scan has one) and one float32 field per
    name in ``features`` (see :data:`FEATURES`). A feature the scan cannot give is a
    :class:`PointfieldError` naming the scan. With ``return_inverse``, also the ``(N,)`` index
    of every input point's representative in the result (-1 for a non-finite point).
    ``origin`` (the grid's corner, default the scan's minimum) and ``floor`` (the z that height is
    measured from, default the 1st percentile of the subsampled z) are the whole scan's when
    ``scan`` is a piece of it.
    """
    finite = ops.finite_rows(scan.points)
    if not finite.any():
        raise PointfieldError(f"{name}: has no points with finite coordinates")
    # In lexicographic order of the coordinates first: a cell's mean is then summed in the same
    # order, and its label and colour taken from the same point, however the file was ordered.
    order = np.lexsort(scan.points.T[::-1])
    ordered = scan.select(order)
    if grid > 0:
        cloud, inverse_ordered = ops.voxel_downsample(ordered, grid, return_inverse=True, origin=origin)
    else:
        cloud = ordered.select(finite[order])
        inverse_ordered = np.full(len(scan), -1, np.int64)
        inverse_ordered[finite[order]] = np.arange(int(finite.sum()))
    inverse = np.empty_like(inverse_ordered)
    inverse[order] = inverse_ordered
    fields: dict[str, np.ndarray] = {}
    if LABEL_FIELD in cloud.fields:
        fields[LABEL_FIELD] = cloud.fields[LABEL_FIELD].astype(np.int64)
    for feature in features:
        fields[feature] = _feature(cloud, feature, name, floor)
    prepared = PointCloud(cloud.points.astype(np.float32), fields, None, {"scan": name})
    return (prepared, inverse) if return_inverse else prepared


def _feature(cloud: PointCloud, feature: str, name: str, floor: float | None = None) -> np.ndarray:
    if feature == "colour":
        if "colors" not in cloud.fields:
            raise PointfieldError(f"{name}: has no colours for the feature 'colour'")
        colours = np.asarray(cloud.fields["colors"], np.float32)[:, :3]
        return colours / 255.0 if colours.max(initial=0) > 1.0 else colours
    if feature == "intensity":
        if "intensity" not in cloud.fields:
            raise PointfieldError(f"{name}: has no intensity for the feature 'intensity'")
        return np.asarray(cloud.fields["intensity"], np.float32).reshape(-1, 1)
    if feature == "normals":
        if "normals" in cloud.fields:
            return np.nan_to_num(np.asarray(cloud.fields["normals"], np.float32))
        return ops.estimate_normals(cloud.points, NORMAL_NEIGHBOURS).astype(np.float32)
    if feature == "height":
        floor = np.percentile(cloud.points[:, 2], 1) if floor is None else floor
        return (cloud.points[:, 2:3] - floor).astype(np.float32)
    raise PointfieldError(f"unknown feature {feature!r}: expected one of {', '.join(FEATURES)}")


class CropFinder:
    """The points of a scan within a crop: a k-d tree over xyz (spheres) or xy (blocks)."""

    def __init__(self, points: np.ndarray, radius: float, shape: str = "sphere"):
        if shape not in CROP_SHAPES:
            raise PointfieldError(f"unknown crop shape {shape!r}: expected sphere or block")
        self.points, self.radius, self.shape = points, radius, shape
        self.tree = cKDTree(points if shape == "sphere" else points[:, :2])

    def within(self, centre: np.ndarray, radius: float | None = None) -> np.ndarray:
        """Sorted indices of the points inside the crop about ``centre``."""
        radius = self.radius if radius is None else radius
        if self.shape == "sphere":
            found = self.tree.query_ball_point(centre, radius)
        else:  # |dx|, |dy| <= radius: the Chebyshev ball in xy
            found = self.tree.query_ball_point(centre[:2], radius, p=np.inf)
        return np.sort(np.asarray(found, np.int64))


def training_transform(radius: float, colour: bool) -> Compose:
    """The papers' augmentations, in metres, then into the unit ball: a turn about the up axis,
    a scale of 0.9..1.1, jitter N(0, 1 cm²) clipped to 5 cm, and for colour Pointcept's
    colour jitter (sigma 0.05) and colour drop (probability 0.2)."""
    steps = [RandomRotate(180.0, "z"), RandomScale(0.9, 1.1, anisotropic=False), RandomJitter(0.01, clip=0.05)]
    if colour:
        steps += [ColourJitter(0.05), ColourDrop(0.2)]
    return Compose([*steps, ScaleBy(1.0 / radius)])


class SceneCrops(CloudDataset):
    """``crops`` class-balanced crops per epoch from prepared scenes (see the module doc).

    ``dataset[i]`` is ``(crop, 0)``: at most ``points`` points drawn at random from the crop,
    centred on its centre, with their fields (``label`` included), then ``transform``. The
    crops of an epoch are drawn from ``(seed, epoch, i)``, so a resumed run sees the same ones.
    """

    def __init__(
        self,
        scenes: Sequence[PointCloud],
        classes: Sequence[str],
        *,
        radius: float,
        points: int,
        crops: int,
        shape: str = "sphere",
        transform=None,
        seed: int = 0,
    ):
        super().__init__(transform, seed)
        self.scenes, self.classes = list(scenes), list(classes)
        self.radius, self.points, self.crops, self.shape = radius, points, crops, shape
        self.finders = [CropFinder(scene.points, radius, shape) for scene in self.scenes]
        labels = np.concatenate([scene.fields[LABEL_FIELD] for scene in self.scenes])
        self.offsets = np.cumsum([0] + [len(scene) for scene in self.scenes])
        self.by_class = [np.flatnonzero(labels == c) for c in range(len(self.classes))]
        self.present = [c for c, members in enumerate(self.by_class) if len(members)]
        if not self.present:
            raise PointfieldError("the training scans have no labelled points")

    def __len__(self) -> int:
        return self.crops

    def load(self, index: int) -> tuple[PointCloud, int]:
        rng = np.random.default_rng([self.seed, self.epoch, index, 1])
        members = self.by_class[self.present[rng.integers(len(self.present))]]
        flat = int(members[rng.integers(len(members))])
        which = int(np.searchsorted(self.offsets, flat, side="right") - 1)
        scene, centre = self.scenes[which], self.scenes[which].points[flat - self.offsets[which]]
        inside = self.finders[which].within(centre)
        if len(inside) > self.points:
            inside = rng.choice(inside, self.points, replace=False)
        crop = scene.select(inside)
        return PointCloud(crop.points - centre, crop.fields), 0

    def class_labels(self) -> np.ndarray:
        return np.zeros(len(self), np.int64)


def class_weights(scenes: Sequence[PointCloud], classes: int) -> np.ndarray:
    """``(classes,)`` loss weights ``w_c = 1 / ln(1.02 + f_c)`` (ENet's), f_c the share of class c
    among the labelled points; scaled to mean 1 over the classes present, 0 for absent ones."""
    counts = np.zeros(classes)
    for scene in scenes:
        labels = scene.fields[LABEL_FIELD]
        counts += np.bincount(labels[labels >= 0], minlength=classes)[:classes]
    share = counts / max(counts.sum(), 1)
    weights = np.where(counts > 0, 1.0 / np.log(1.02 + share), 0.0)
    present = counts > 0
    return weights / weights[present].mean() if present.any() else weights


def cover_cells(points: np.ndarray, radius: float) -> np.ndarray:
    """``(N, 2)`` int64: the cover cell (column) of each point, ``floor((x, y) / (COVER_CELL_RADII * radius))``."""
    return np.floor(points[:, :2].astype(np.float64) / (COVER_CELL_RADII * radius)).astype(np.int64)


def cover(
    finder: CropFinder, points_per_chunk: int, reach: tuple[np.ndarray, np.ndarray] | None = None
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``(centre (3,), chunk indices)`` for every chunk of every window covering the scan (module doc).

    Cells are taken in order of their (i, j), each point of a cell in coordinate order; a window
    marks as covered only the points of its own cell, so a cell's windows are the same whatever
    its neighbours hold. ``reach`` ``(low (2,), high (2,))``, an x y box, keeps only the windows
    of the cells that meet it.
    """
    points = finder.points
    cells = cover_cells(points, finder.radius)
    order = np.lexsort((points[:, 2], points[:, 1], points[:, 0], cells[:, 1], cells[:, 0]))
    if reach is not None:
        side = COVER_CELL_RADII * finder.radius
        meets = np.all((cells + 1) * side >= reach[0], axis=1) & np.all(cells * side <= reach[1], axis=1)
        order = order[meets[order]]
    covered = np.zeros(len(points), bool)
    for position in order:
        if covered[position]:
            continue
        centre = points[position].astype(np.float64)
        core = finder.within(centre, finder.radius * CORE_FRACTION)
        covered[core[(cells[core] == cells[position]).all(axis=1)]] = True
        window = finder.within(centre)
        ranked = window[ops.canonical_sample(points[window], len(window))]
        for chunk in np.array_split(ranked, -(-len(ranked) // points_per_chunk)):
            yield centre, np.sort(chunk)


def vote(
    model: torch.nn.Module,
    scene: PointCloud,
    *,
    radius: float,
    points: int,
    shape: str,
    features: Sequence[str],
    classes: int,
    device: torch.device,
    batch_size: int = 8,
    wanted: np.ndarray | None = None,
    reach: tuple[np.ndarray, np.ndarray] | None = None,
    bar=None,
) -> np.ndarray:
    """``(N, classes)`` float32: each point's class probabilities averaged over the windows holding it.

    ``scene`` is a prepared scan (:func:`prepare_scene`); ``model`` maps crops in the unit ball
    to per-point scores, as in training. With ``wanted`` (``(N,)`` bool), only the chunks that
    hold a wanted point are run, and with ``reach`` only the windows of the cover cells meeting
    that box (:func:`cover`): the other points' rows are then partial (a tile's halo).
    ``bar``, a tqdm bar, advances by the wanted points (all, without ``wanted``) as their
    first window is run.
    """
    finder = CropFinder(scene.points, radius, shape)
    # Every crop padded to ``points``: its scores are then its own, whichever crops share its batch,
    # so a scan's tiles, streamed or in separate files, get the votes the whole scan gives them.
    collate = CloudCollate(features, length=points)
    totals = np.zeros((len(scene), classes), np.float64)
    counts = np.zeros(len(scene), np.int64)
    counted = np.zeros(len(scene), bool) if bar is not None else None
    was_training = model.training
    model.eval()

    def run(pending: list[tuple[np.ndarray, np.ndarray]]) -> None:
        samples = []
        for centre, chunk in pending:
            crop = scene.select(chunk)
            samples.append((PointCloud(((crop.points - centre) / radius).astype(np.float32), crop.fields), 0))
        batch = collate(samples).to(device)
        with torch.inference_mode():
            probabilities = torch.softmax(model(batch.points, batch.features, batch.mask).float(), dim=-1)
        probabilities = probabilities.cpu().numpy()
        for row, (_, chunk) in enumerate(pending):
            totals[chunk] += probabilities[row, : len(chunk)]
            counts[chunk] += 1
            if counted is not None:
                fresh = chunk[~counted[chunk] & (True if wanted is None else wanted[chunk])]
                counted[fresh] = True
                bar.update(len(fresh))

    pending: list[tuple[np.ndarray, np.ndarray]] = []
    for window in cover(finder, points, reach):
        if wanted is not None and not wanted[window[1]].any():
            continue
        pending.append(window)
        if len(pending) == batch_size:
            run(pending)
            pending = []
    if pending:
        run(pending)
    model.train(was_training)
    return (totals / np.maximum(counts, 1)[:, None]).astype(np.float32)
