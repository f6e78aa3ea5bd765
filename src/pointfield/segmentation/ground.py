"""Ground and non-ground of aerial or terrestrial lidar: the cloth simulation filter (Zhang et al. 2016).

The cloud is turned upside down and a cloth of rigid particles, ``cloth_resolution`` apart, is
dropped on it under gravity; where it rests is the ground surface, and points within
``class_threshold`` of the cloth are ground. The library is ``cloth-simulation-filter``
(``import CSF``, the authors' C++ code); this module only sets it up and reads its answer.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from collections.abc import Iterator

import numpy as np

from pointfield.clouds.ops import finite_rows

LAS_GROUND = 2
LAS_UNCLASSIFIED = 1


def default_cloth_resolution(points: np.ndarray) -> float:
    """Twice the points' mean x-y spacing, ``2 sqrt(area of the x-y box / finite points)``: what ``cloud
    ground`` uses when no ``--resolution`` is given (the threshold is then half of it)."""
    finite = np.asarray(points)[finite_rows(points)]
    extent = np.ptp(finite[:, :2], axis=0) if len(finite) else np.zeros(2)
    return 2.0 * float(np.sqrt(max(extent[0] * extent[1], 1e-12) / max(len(finite), 1)))


def ground_mask(points: np.ndarray, cloth_resolution: float = 0.5, rigidness: int = 3, class_threshold: float = 0.5,
                slope_smooth: bool = False, iterations: int = 500, time_step: float = 0.65) -> np.ndarray:
    """``(N,)`` bool: the points of ``(N, 3)`` (z up) that the cloth settles on. NaN points are not ground.

    ``rigidness`` 1 for steep terrain, 2 for relief, 3 for flat land (the authors' scenes);
    ``slope_smooth`` post-processes steep slopes. Defaults are the library's, for flat land.
    """
    import CSF

    points = np.asarray(points)
    finite = np.flatnonzero(finite_rows(points))
    mask = np.zeros(len(points), bool)
    if len(finite) == 0:
        return mask
    valid = points[finite].astype(np.float64)
    # CSF works in float; centring keeps UTM-sized coordinates' digits.
    valid = valid - valid.mean(axis=0)
    cloth = CSF.CSF()
    cloth.params.bSloopSmooth = slope_smooth
    cloth.params.cloth_resolution = cloth_resolution
    cloth.params.rigidness = rigidness
    cloth.params.class_threshold = class_threshold
    cloth.params.interations = iterations
    cloth.params.time_step = time_step
    cloth.setPointCloud(valid)
    ground, other = CSF.VecInt(), CSF.VecInt()
    with _c_stdout_silenced():
        cloth.do_filtering(ground, other, False)
    mask[finite[np.asarray(list(ground), np.int64)]] = True
    return mask


@contextlib.contextmanager
def _c_stdout_silenced() -> Iterator[None]:
    """File descriptor 1 sent to /dev/null meanwhile: CSF's C++ prints its progress ("[0] Configuring
    terrain...", "[0]  - post handle...") on standard output, where it would break ``cloud ground --json``."""
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output to guard
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)  # what C's stdio still buffers goes to /dev/null too, not after the restore
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def ground_classification(mask: np.ndarray, classification: np.ndarray | None = None) -> np.ndarray:
    """``(N,)`` uint8 LAS classes: 2 for ground, else the given class (1, unclassified, where it said ground or was absent)."""
    if classification is None:
        out = np.full(len(mask), LAS_UNCLASSIFIED, np.uint8)
    else:
        out = np.asarray(classification).astype(np.uint8, copy=True)
        out[out == LAS_GROUND] = LAS_UNCLASSIFIED
    out[mask] = LAS_GROUND
    return out


def iou(predicted: np.ndarray, truth: np.ndarray) -> float:
    """``|predicted & truth| / |predicted | truth|`` of two boolean masks (1.0 when both are empty)."""
    union = np.logical_or(predicted, truth).sum()
    return float(np.logical_and(predicted, truth).sum() / union) if union else 1.0
