"""``crop``: the points inside a box or a polygon, streamed with bounded memory.

- ``box``: ``(xmin, ymin, xmax, ymax)`` (any z) or ``(xmin, ymin, zmin, xmax, ymax, zmax)``;
  bounds included, ``min <= p <= max`` on each axis given.
- ``polygon``: an ``(K, 2)`` array of x y vertices, or a file: plain text with one ``x y``
  (or ``x,y``) vertex per line, or GeoJSON (a Polygon, MultiPolygon, Feature or
  FeatureCollection; every ring of the first polygon, so holes are holes). Inside is decided in
  x y by the even-odd rule (a ray from the point crosses the boundary an odd number of times).

Points with a NaN coordinate are never inside. :func:`crop_cloud` is the in-memory definition.
"""

from __future__ import annotations

import json
import os
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.errors import PointfieldError
from pointfield.streaming.jobs import output_done, streaming_job, summary
from pointfield.streaming.memory import DEFAULT_MEMORY
from pointfield.streaming.select import select_to_file


def box_mask(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: points with ``min <= p <= max`` on each axis the box gives."""
    half = len(box) // 2
    low, high = box[:half], box[half:]
    inside = np.ones(len(points), bool)
    for axis in range(half):
        inside &= (points[:, axis] >= low[axis]) & (points[:, axis] <= high[axis])
    return inside


def polygon_mask(points: np.ndarray, rings: list[np.ndarray]) -> np.ndarray:
    """``(N,)`` bool: points inside ``rings`` (each ``(K, 2)``) by the even-odd rule in x y."""
    x = points[:, 0].astype(np.float64)
    y = points[:, 1].astype(np.float64)
    inside = np.zeros(len(points), bool)
    for ring in rings:
        low, high = ring.min(axis=0), ring.max(axis=0)
        near = np.flatnonzero((x >= low[0]) & (x <= high[0]) & (y >= low[1]) & (y <= high[1]))
        px, py = x[near], y[near]
        crossings = np.zeros(len(near), bool)
        for (x1, y1), (x2, y2) in zip(ring, np.roll(ring, -1, axis=0), strict=True):
            spans = (y1 > py) != (y2 > py)
            if not spans.any():
                continue
            crossing_x = x1 + (py[spans] - y1) * (x2 - x1) / (y2 - y1)
            crossings[np.flatnonzero(spans)[px[spans] < crossing_x]] ^= True
        inside[near] ^= crossings
    return inside


def read_polygon(path: str | os.PathLike[str]) -> list[np.ndarray]:
    """The rings of a polygon file (module docstring), each ``(K, 2)`` float64."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    if text.lstrip().startswith("{"):
        geometry = json.loads(text)
        if geometry.get("type") == "FeatureCollection":
            geometry = geometry["features"][0]
        if geometry.get("type") == "Feature":
            geometry = geometry["geometry"]
        kind, coordinates = geometry.get("type"), geometry.get("coordinates")
        if kind == "MultiPolygon":
            coordinates = coordinates[0]
        elif kind != "Polygon":
            raise PointfieldError(f"{path}: GeoJSON {kind!r}; expected a Polygon or MultiPolygon")
        rings = [np.asarray(ring, np.float64)[:, :2] for ring in coordinates]
    else:
        rows = [line.replace(",", " ").split() for line in text.splitlines()]
        try:
            rings = [np.array([[float(r[0]), float(r[1])] for r in rows if r and not r[0].startswith("#")])]
        except (ValueError, IndexError):
            raise PointfieldError(f"{path}: expected one 'x y' vertex per line, or GeoJSON") from None
    if any(len(ring) < 3 for ring in rings):
        raise PointfieldError(f"{path}: a polygon ring needs at least 3 vertices")
    return rings


def _area(box: Any, polygon: Any) -> tuple[np.ndarray | None, list[np.ndarray] | None]:
    if (box is None) == (polygon is None):
        raise PointfieldError("give exactly one of box and polygon")
    if box is not None:
        box = np.asarray(box, np.float64).reshape(-1)
        half = len(box) // 2
        if len(box) not in (4, 6) or np.any(box[:half] > box[half:]):
            raise PointfieldError(f"box {box.tolist()}: expected xmin ymin [zmin] xmax ymax [zmax], min <= max")
        return box, None
    if isinstance(polygon, (str, os.PathLike)):
        return None, read_polygon(polygon)
    rings = [np.asarray(polygon, np.float64)]
    if rings[0].ndim != 2 or rings[0].shape[1] < 2 or len(rings[0]) < 3:
        raise PointfieldError("polygon: expected at least 3 x y vertices")
    return None, [rings[0][:, :2]]


def keep_inside(box: np.ndarray | None, rings: list[np.ndarray] | None, cloud: PointCloud, index: np.ndarray) -> PointCloud:
    """The rule of ``crop``: the points of ``cloud`` inside the box or the polygon."""
    mask = box_mask(cloud.points, box) if box is not None else polygon_mask(cloud.points, rings)
    return cloud.select(mask)


def crop_cloud(cloud: PointCloud, box: Any = None, polygon: Any = None) -> PointCloud:
    """In memory, the points of ``cloud`` inside ``box`` or ``polygon`` (module docstring)."""
    area_box, rings = _area(box, polygon)
    return keep_inside(area_box, rings, cloud, np.arange(len(cloud)))


def crop(
    source: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    box: Any = None,
    polygon: Any = None,
    encoding: str | None = None,
    memory: str | int = DEFAULT_MEMORY,
    points: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    scratch: str | os.PathLike[str] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    columns: int | None = None,
) -> dict[str, Any]:
    """Write the points of ``source`` inside ``box`` or ``polygon`` to ``out``, chunk by chunk.

    Options as :func:`~pointfield.streaming.downsample`. Returns a summary.
    """
    area_box, rings = _area(box, polygon)
    if output_done(out, overwrite):
        return summary(source=source, out=out, skipped=True)
    with streaming_job([source], columns=columns, memory=memory, points=points, workers=workers,
                       scheduler=scheduler, client=client, scratch=scratch, progress=progress) as job:
        written = select_to_file(job, Path(out), partial(keep_inside, area_box, rings), encoding, "crop")
    return summary(source=source, out=out, input_points=job.source.count, output_points=written, skipped=False)
