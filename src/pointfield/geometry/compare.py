"""How close reconstructed geometry is to a true surface: the DTU / Tanks-and-Temples scores.

Both sides are point sets: samples of the true surface (dense), and the reconstruction's points
(a cloud's points, or uniform samples of a mesh's surface, :func:`sample_mesh`). With nearest
neighbours found by a k-d tree::

    accuracy     = mean over reconstructed points of the distance to the nearest true point
    completeness = mean over true points of the distance to the nearest reconstructed point
    chamfer      = (accuracy + completeness) / 2                      (DTU's "overall")
    precision    = fraction of reconstructed points within `threshold` of the truth
    recall       = fraction of true points within `threshold` of the reconstruction
    fscore       = 2 precision recall / (precision + recall)          (Tanks and Temples)

Distances are in scene units; :func:`surface_scores` also gives them relative to a length
(e.g. the bounding-box diagonal) when one is passed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError


def sample_mesh(mesh: Mesh, count: int, seed: int = 0) -> np.ndarray:
    """``(count, 3)`` points uniformly distributed over the mesh's surface (by area)."""
    if mesh.faces is None or len(mesh.faces) == 0:
        raise PointfieldError("a mesh with no faces has no surface to sample")
    corners = np.asarray(mesh.points, np.float64)[mesh.faces]  # (F, 3, 3)
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    generator = np.random.default_rng(seed)
    faces = generator.choice(len(areas), size=count, p=areas / areas.sum())
    # Uniform barycentric coordinates: fold the unit square's upper triangle onto the lower one.
    u, v = generator.random((2, count))
    outside = u + v > 1
    u[outside], v[outside] = 1 - u[outside], 1 - v[outside]
    chosen = corners[faces]
    return chosen[:, 0] + u[:, None] * (chosen[:, 1] - chosen[:, 0]) + v[:, None] * (chosen[:, 2] - chosen[:, 0])


def surface_scores(reconstruction: np.ndarray, truth: np.ndarray, threshold: float,
                   unit: float | None = None) -> dict[str, Any]:
    """Accuracy, completeness, Chamfer distance, precision, recall and F-score (module docstring).

    ``reconstruction`` ``(N, 3)`` and ``truth`` ``(M, 3)`` points; ``threshold`` for precision and
    recall, in scene units. With ``unit`` (e.g. the true bounding-box diagonal), the distances are
    also given as fractions of it (``*_relative``).
    """
    from scipy.spatial import cKDTree

    reconstruction = np.asarray(reconstruction, np.float64)
    truth = np.asarray(truth, np.float64)
    if len(reconstruction) == 0 or len(truth) == 0:
        raise PointfieldError(f"surface scores need points on both sides, got {len(reconstruction)} and {len(truth)}")
    to_truth, _ = cKDTree(truth).query(reconstruction, workers=-1)
    to_reconstruction, _ = cKDTree(reconstruction).query(truth, workers=-1)
    precision = float(np.mean(to_truth <= threshold))
    recall = float(np.mean(to_reconstruction <= threshold))
    scores = {
        "accuracy": float(to_truth.mean()),
        "completeness": float(to_reconstruction.mean()),
        "chamfer": float((to_truth.mean() + to_reconstruction.mean()) / 2),
        "precision": precision,
        "recall": recall,
        "fscore": 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0,
        "threshold": float(threshold),
        "points": len(reconstruction),
    }
    if unit is not None:
        for name in ("accuracy", "completeness", "chamfer"):
            scores[f"{name}_relative"] = scores[name] / unit
    return scores
