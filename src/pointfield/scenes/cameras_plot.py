"""A picture of a scene's cameras: one frustum per camera, coloured by split, with the sparse points.

Frustums are drawn by unprojecting the image corners (so distortion and off-centre principal
points show), with a small triangle on the image's top edge to show which way is up. The world
is turned so that the cameras' mean up direction is vertical in the picture.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from pointfield.atomic import atomic_path
from pointfield.scenes.scene import Scene

SPLIT_COLORS = {"train": "tab:blue", "val": "tab:orange", "test": "tab:green", "no image": "tab:gray"}


def frustum_segments(scene: Scene, depth: float) -> np.ndarray:
    """Line segments ``(N, 11, 2, 3)`` of every camera's frustum at z-depth ``depth``.

    Per camera: 4 edges from the centre to the image corners, 4 edges of the image rectangle,
    and 3 edges of an "up" triangle above the top edge.
    """
    cameras = scene.cameras.to("cpu", torch.float64)
    count = len(cameras)
    width, height = cameras.width.double(), cameras.height.double()
    zero = torch.zeros(count, dtype=torch.float64)
    corners = torch.stack(
        [
            torch.stack([zero, zero], -1),
            torch.stack([width, zero], -1),
            torch.stack([width, height], -1),
            torch.stack([zero, height], -1),
            torch.stack([0.3 * width, zero], -1),
            torch.stack([0.7 * width, zero], -1),
            torch.stack([0.5 * width, -0.25 * height], -1),
        ],
        dim=1,
    )
    camera_index = torch.arange(count)[:, None].expand(-1, 7)
    points = cameras.unproject(
        camera_index, corners, torch.full((count, 7), depth, dtype=torch.float64)
    ).numpy()
    centers = cameras.centers.numpy()
    pairs = [(None, k) for k in range(4)] + [(0, 1), (1, 2), (2, 3), (3, 0), (4, 6), (6, 5), (5, 4)]
    segments = np.empty((count, len(pairs), 2, 3))
    for slot, (start, end) in enumerate(pairs):
        segments[:, slot, 0] = centers if start is None else points[:, start]
        segments[:, slot, 1] = points[:, end]
    return segments


def _up_rotation(scene: Scene) -> np.ndarray:
    """Rotation taking the cameras' mean up direction (-y camera axis) to world +z."""
    up = -scene.cameras.rotations[:, :, 1].double().mean(0).cpu().numpy()
    norm = np.linalg.norm(up)
    if norm < 1e-6:
        return np.eye(3)
    up = up / norm
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sine, cosine = np.linalg.norm(axis), up[2]
    if sine < 1e-9:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    axis = axis / sine
    skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + sine * skew + (1 - cosine) * skew @ skew


def draw_cameras(
    scene: Scene, out: str | os.PathLike[str], *, max_points: int = 20000, title: str | None = None
) -> Path:
    """Write a PNG of ``scene``'s camera frustums and (up to ``max_points``) sparse points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    out = Path(out)
    centers = scene.cameras.centers.double().cpu().numpy()
    points = colors = None
    if scene.points is not None and len(scene.points):
        chosen = np.random.default_rng(0).permutation(len(scene.points))[:max_points]
        points = np.asarray(scene.points.points, dtype=np.float64)[chosen]
        finite = np.isfinite(points).all(1)
        points = points[finite]
        if "colors" in scene.points.fields:
            colors = np.asarray(scene.points.fields["colors"])[chosen][finite][:, :3].astype(np.float64)
            colors = colors / (255.0 if colors.max(initial=0) > 1 else 1.0)
    # Frustums are 8 % of the picture's size (cameras plus the bulk of the points).
    extent_of = [centers] + (
        [np.clip(points, *np.percentile(points, [2, 98], axis=0))]
        if points is not None and len(points)
        else []
    )
    everything = np.concatenate(extent_of)
    extent = float((everything.max(0) - everything.min(0)).max()) if len(everything) > 1 else 0.0
    rotation = _up_rotation(scene)
    segments = frustum_segments(scene, 0.08 * extent if extent > 0 else 1.0) @ rotation.T

    figure = plt.figure(figsize=(8, 8), dpi=110)
    axes = figure.add_subplot(projection="3d")
    split_of = np.full(len(scene), "", dtype=object)
    for name, indices in scene.splits.items():
        split_of[indices] = name
    split_of[np.array([not frame.has_image for frame in scene.frames], dtype=bool)] = "no image"
    for name in dict.fromkeys(split_of):
        chosen = split_of == name
        color = SPLIT_COLORS.get(name, "tab:purple")
        label = f"{name or 'no split'} ({int(chosen.sum())})"
        axes.add_collection3d(
            Line3DCollection(segments[chosen].reshape(-1, 2, 3), colors=color, linewidths=0.8, label=label)
        )
    extent_points = [segments.reshape(-1, 3)]
    if points is not None and len(points):
        rotated = points @ rotation.T
        axes.scatter(
            rotated[:, 0],
            rotated[:, 1],
            rotated[:, 2],
            s=1.5,
            c=colors if colors is not None else "k",
            depthshade=False,
        )
        low, high = np.percentile(rotated, [2, 98], axis=0)
        extent_points.append(np.clip(rotated, low, high))
    everything = np.concatenate(extent_points)
    middle = (everything.max(0) + everything.min(0)) / 2
    half = max(float((everything.max(0) - everything.min(0)).max()) / 2, 1e-6) * 1.05
    axes.set_xlim(middle[0] - half, middle[0] + half)
    axes.set_ylim(middle[1] - half, middle[1] + half)
    axes.set_zlim(middle[2] - half, middle[2] + half)
    axes.set_box_aspect((1, 1, 1))
    rotated_note = (
        "" if np.allclose(rotation, np.eye(3), atol=0.17) else " (turned so the cameras' up is vertical)"
    )
    axes.set_xlabel("x" if not rotated_note else "")
    axes.set_ylabel("y" if not rotated_note else "")
    axes.set_zlabel("z" if not rotated_note else "")
    point_text = f", {len(scene.points)} points" if scene.points is not None else ""
    heading = title or f"{scene.metadata.get('format', 'scene')}: {len(scene)} cameras{point_text}"
    axes.set_title(heading + rotated_note, fontsize=10)
    axes.legend(loc="upper left", fontsize=8)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as temporary:
        figure.savefig(temporary, format="png")
    plt.close(figure)
    return out
