"""Where a cloud was seen from: the sensor's position and which way was up, when the file says.

A depth camera's organised frame, a PCD with a ``VIEWPOINT``, a PTX scan with its scanner position,
an E57 scan with its pose: each knows where the sensor stood. A viewer that opens such a cloud from
an arbitrary corner shows a Kinect frame (x right, y *down*, z forward) from below and behind,
upside down; opened from the sensor, it looks as the sensor saw it.

:func:`sensor_view` reads that from a :class:`~pointfield.clouds.cloud.PointCloud`:

=====================  ======================================  ===========================================
source                 position                                up
=====================  ======================================  ===========================================
organised cloud        PCD ``VIEWPOINT`` translation (else 0)  against the direction rows grow in
                                                               (rows run top to bottom, as in an image)
PCD ``VIEWPOINT``      its translation                         z, the height axis of most scans
(not the default)
PTX                    the first scan's ``scanner_position``   its third ``scanner_axes`` row
E57                    the first scan's pose translation       its pose's z axis
=====================  ======================================  ===========================================

The view looks from the position at the median of the finite points (robust to a few far
returns), with ``up`` made perpendicular to that direction. The up of an organised frame comes from
the grid itself rather than from the ``VIEWPOINT`` quaternion, whose meaning differs between the
programs that write it (PCL's OpenNI grabber writes ``0 0 0 1 0 0 0`` and also ``0 0 0 0 1 0 0`` for
frames with the same axes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from pointfield.clouds.cloud import PointCloud

DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
"""PCD's ``VIEWPOINT`` when the writer knew none: at the origin, no rotation (tx ty tz qw qx qy qz)."""
HEIGHT_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SensorView:
    """A first look from the sensor: ``eye`` (where it stood), ``target`` (the median point it
    saw), ``up`` (unit, perpendicular to ``target - eye``); all ``(3,)`` float64, real coordinates."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray


def sensor_view(cloud: PointCloud) -> SensorView | None:
    """The view from where ``cloud`` was seen (see the module doc); None when the file does not say,
    or when its points give no direction to look in (none finite, or all at the sensor)."""
    points = np.asarray(cloud.points, np.float64)
    metadata = cloud.metadata
    viewpoint = metadata.get("viewpoint")
    up = None
    if cloud.shape is not None and cloud.shape[0] > 1:
        eye = np.asarray(viewpoint[:3], np.float64) if viewpoint is not None else np.zeros(3)
        up = _up_of_rows(points.reshape(*cloud.shape, 3))
    elif viewpoint is not None and tuple(float(v) for v in viewpoint) != DEFAULT_VIEWPOINT:
        eye = np.asarray(viewpoint[:3], np.float64)
    elif metadata.get("ptx_scans"):
        scan = metadata["ptx_scans"][0]
        eye = np.asarray(scan["scanner_position"], np.float64)
        up = np.asarray(scan["scanner_axes"], np.float64)[2]
    elif metadata.get("e57_scans"):
        scan = metadata["e57_scans"][0]
        eye = np.asarray(scan["translation"], np.float64)
        w, x, y, z = scan["rotation"]  # E57's order; scipy's is (x, y, z, w)
        up = Rotation.from_quat([x, y, z, w]).apply(HEIGHT_AXIS)
    else:
        return None
    finite = points[np.all(np.isfinite(points), axis=1)]
    if not len(finite) or not np.all(np.isfinite(eye)):
        return None
    target = np.median(finite, axis=0)
    forward = target - eye
    if np.linalg.norm(forward) < 1e-12:
        return None
    forward /= np.linalg.norm(forward)
    up = HEIGHT_AXIS if up is None or not np.all(np.isfinite(up)) else up
    up = up - forward * float(up @ forward)
    if np.linalg.norm(up) < 1e-6:  # looking straight along the up axis: any perpendicular will do
        up = np.cross(forward, [1.0, 0.0, 0.0] if abs(forward[0]) < 0.9 else [0.0, 1.0, 0.0])
    return SensorView(eye, target, up / np.linalg.norm(up))


def _up_of_rows(grid: np.ndarray) -> np.ndarray | None:
    """Up in an organised ``(H, W, 3)`` grid: the mean step from one row to the next, reversed
    (image rows run downwards); None where no two vertically adjacent points are finite."""
    steps = grid[1:] - grid[:-1]
    steps = steps[np.all(np.isfinite(steps), axis=-1)]
    if not len(steps):
        return None
    down = steps.mean(axis=0)
    return -down if np.linalg.norm(down) > 0 else None

