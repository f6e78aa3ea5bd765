"""How far recovered camera poses are from known ones, after the one similarity that relates them.

Structure from motion fixes poses only up to a similarity (scale, rotation, translation), so two
sets of poses are compared after aligning the found ones onto the given ones once:

- rotation ``R``: the chordal mean of ``R_given_i R_found_i^T`` over all frames, i.e. the
  rotation nearest (in Frobenius norm) to their sum, by SVD with the determinant kept +1;
- scale ``s`` and translation ``t``: least squares on the camera centres with ``R`` fixed
  (Umeyama's closed form): ``s = sum <g_i - g, R (f_i - f)> / sum |f_i - f|^2``, ``t = g - s R f``
  with ``g``, ``f`` the mean given and found centres.

Then per frame: the rotation error is the angle of ``R_given_i^T R R_found_i`` in degrees, and the
centre error ``|s R c_found_i + t - c_given_i|`` divided by the extent of the given centres (the
largest distance between two of them), so that it reads the same at any scene scale.

Poses are camera-to-world in pointfield's convention (OpenCV axes; see
:mod:`pointfield.scenes.cameras`), ``(N, 3, 4)`` or ``(N, 4, 4)``, the same frames in the same order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PoseErrors:
    """Per-frame errors after alignment, and the alignment: ``world_given = scale * rotation @ world_found + translation``."""

    rotation_degrees: np.ndarray
    centre_fraction: np.ndarray
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    extent: float

    @property
    def median_rotation_degrees(self) -> float:
        return float(np.median(self.rotation_degrees))

    @property
    def median_centre_fraction(self) -> float:
        return float(np.median(self.centre_fraction))

    def summary(self) -> dict[str, float]:
        return {
            "frames": len(self.rotation_degrees),
            "median_rotation_degrees": self.median_rotation_degrees,
            "max_rotation_degrees": float(self.rotation_degrees.max()),
            "median_centre_percent": 100 * self.median_centre_fraction,
            "max_centre_percent": 100 * float(self.centre_fraction.max()),
        }


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation nearest ``matrix`` (3, 3) in Frobenius norm (its polar factor, determinant +1)."""
    u, _, vt = np.linalg.svd(matrix)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return u @ flip @ vt


def rotation_angle_degrees(rotations: np.ndarray) -> np.ndarray:
    """Angles of rotations ``(N, 3, 3)`` in degrees: ``atan2(sin, cos)``, exact near 0 and 180.

    ``cos = (trace - 1) / 2``; ``sin = |v| / 2`` with ``v`` the skew part
    ``(R32 - R23, R13 - R31, R21 - R12)``. (``arccos`` of the trace alone loses the small angles
    that pose errors are made of to rounding.)
    """
    cosine = (np.trace(rotations, axis1=-2, axis2=-1) - 1) / 2
    skew = np.stack(
        [
            rotations[..., 2, 1] - rotations[..., 1, 2],
            rotations[..., 0, 2] - rotations[..., 2, 0],
            rotations[..., 1, 0] - rotations[..., 0, 1],
        ],
        axis=-1,
    )
    return np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1) / 2, cosine))


def pose_errors(found, given) -> PoseErrors:
    """Align ``found`` camera-to-world poses onto ``given`` ones and measure what is left (module docstring)."""
    found = np.asarray(found, np.float64)[:, :3, :]
    given = np.asarray(given, np.float64)[:, :3, :]
    if found.shape != given.shape or len(found) < 2:
        raise ValueError(
            f"pose_errors needs the same two or more frames on both sides, got {found.shape} and {given.shape}"
        )
    found_rotations, found_centres = found[:, :, :3], found[:, :, 3]
    given_rotations, given_centres = given[:, :, :3], given[:, :, 3]
    rotation = nearest_rotation(np.einsum("nij,nkj->ik", given_rotations, found_rotations))
    found_centred = (found_centres - found_centres.mean(0)) @ rotation.T
    given_centred = given_centres - given_centres.mean(0)
    scale = float((given_centred * found_centred).sum() / max((found_centred**2).sum(), 1e-300))
    translation = given_centres.mean(0) - scale * rotation @ found_centres.mean(0)
    aligned_centres = scale * found_centres @ rotation.T + translation
    extent = float(np.max(np.linalg.norm(given_centres[:, None] - given_centres[None], axis=-1)))
    residual_rotations = np.einsum("nji,jk,nkl->nil", given_rotations, rotation, found_rotations)
    return PoseErrors(
        rotation_degrees=rotation_angle_degrees(residual_rotations),
        centre_fraction=np.linalg.norm(aligned_centres - given_centres, axis=1) / max(extent, 1e-300),
        scale=scale,
        rotation=rotation,
        translation=translation,
        extent=extent,
    )
