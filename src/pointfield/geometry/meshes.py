"""Meshes from any trained scene model: rendered depth fused into a TSDF, then marching cubes.

::

    export_mesh("runs/lego-ngp", "lego.ply", resolution=256, faces=200_000)   # or: nerf export RUN --mesh

1. Render the run from its training views (or a path), through the one run interface; pixels
   less opaque than ``min_opacity`` count as empty.
2. Fuse their z-depth and colour into a :class:`~pointfield.geometry.tsdf.TSDFVolume` over the
   box to reconstruct: ``crop`` if given, else the scene's box -- its ``aabb`` for an object,
   the region of interest the contraction leaves undistorted for an unbounded capture
   (:func:`pointfield.fields.scene_box.scene_bounds`, the box the hash-grid field trains in).
3. Marching cubes at the zero level (scikit-image), only between observed voxels; vertex colours
   from the grid.
4. Drop floating pieces: connected components with fewer than ``min_component`` of the faces.
5. Optionally decimate to ``faces`` triangles (fast-simplification, quadric error), colours
   carried over from the nearest original vertex.
6. Write PLY or OFF (pointfield's writers), OBJ, STL or GLB (trimesh), atomically, by the format registry.

``method="density"`` replaces steps 1 to 3 for a bounded field run: marching cubes on the field's
density itself, the training views rendered coarsely only to fill what they do not see
(:mod:`pointfield.geometry.density`). ``method="sdf"``, the default for a run of the neural SDF
(``--model sdf``), replaces them all: the zero level set of its signed distance, the largest
piece, closed (:mod:`pointfield.geometry.sdf_mesh`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.geometry.clouds import cameras_of, open_scene_run, rendered_depth_maps
from pointfield.geometry.density import (
    default_threshold,
    density_field,
    mesh_from_density,
)
from pointfield.geometry.sdf_mesh import mesh_from_sdf
from pointfield.geometry.tsdf import TSDFVolume, fuse, grid_shape

MESH_SUFFIXES = (".ply", ".off", ".obj", ".glb", ".stl")
MESH_METHODS = ("tsdf", "density", "sdf")
"""``--method``: fuse rendered depth (any scene run), marching cubes on a bounded field's density, or
the zero level set of a neural SDF run. None picks "sdf" for an sdf run and "tsdf" for any other."""
DEFAULT_MEMORY_FRACTION = 0.5
"""A TSDF grid may take at most this fraction of the machine's memory (the rest is for everything else)."""


def mesh_from_volume(volume: TSDFVolume, min_component: float = 0.01) -> Mesh:
    """Marching cubes on the TSDF's zero level; vertex ``colors`` uint8; small components dropped."""
    from skimage.measure import marching_cubes

    tsdf, observed = volume.dense()
    if tsdf.min() >= 0 or tsdf.max() <= 0:
        raise PointfieldError("the fused depth holds no surface (no voxel is behind one); nothing to mesh")
    vertices, faces, _, _ = marching_cubes(tsdf, level=0.0, allow_degenerate=False)
    faces = faces[_between_observed(vertices, observed)[faces].all(axis=1)]
    if len(faces) == 0:
        raise PointfieldError("marching cubes found no surface in the fused depth")
    world = volume.low.cpu().numpy().astype(np.float64) + (vertices.astype(np.float64) + 0.5) * volume.voxel
    colours = volume.colors_at(torch.from_numpy(world).float()).cpu().numpy()
    mesh = _compact(Mesh(world, {"colors": _as_uint8(colours)}, faces=faces.astype(np.int64)), faces)
    return drop_small_components(mesh, min_component)


def face_components(mesh: Mesh) -> np.ndarray:
    """``(F,)`` the connected piece of each triangle of ``mesh`` (pieces join at shared vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(mesh.faces, np.int64)
    count = len(mesh.points)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(count, count))
    _, labels = connected_components(graph, directed=False)
    return labels[faces[:, 0]]


def drop_small_components(mesh: Mesh, min_fraction: float) -> Mesh:
    """Keep the connected pieces holding at least ``min_fraction`` of the faces (the largest always)."""
    faces = mesh.faces
    face_labels = face_components(mesh)
    sizes = np.bincount(face_labels)
    keep_labels = (sizes >= min_fraction * len(faces)) | (sizes == sizes.max())
    kept_faces = faces[keep_labels[face_labels]]
    return _compact(mesh, kept_faces)


def decimate(mesh: Mesh, faces: int) -> Mesh:
    """At most ``faces`` triangles by quadric edge collapse (fast-simplification); colours from the nearest old vertex."""
    import fast_simplification
    from scipy.spatial import cKDTree

    if len(mesh.faces) <= faces:
        return mesh
    points, triangles = fast_simplification.simplify(
        mesh.points.astype(np.float32), mesh.faces.astype(np.int32), target_count=int(faces)
    )
    _, nearest = cKDTree(mesh.points).query(points, workers=-1)
    fields = {name: values[nearest] for name, values in mesh.fields.items()}
    return Mesh(points.astype(np.float64), fields, faces=triangles.astype(np.int64))


def write_mesh(path: str | os.PathLike[str], mesh: Mesh) -> None:
    """PLY / OFF through pointfield's writers, OBJ / STL / GLB through trimesh, all by the format
    registry (so what is written here reads back with :func:`pointfield.read`). Atomic either way."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise PointfieldError(f"{path}: a mesh is written as {', '.join(MESH_SUFFIXES)}, not {suffix or 'no suffix'}")
    from pointfield.clouds.formats.registry import write

    write(path, mesh)


def export_mesh(
    run: str | os.PathLike[str] | Any,
    out: str | os.PathLike[str],
    *,
    resolution: int = 256,
    method: str | None = None,
    threshold: float | None = None,
    path: str = "dataset",
    frames: int | None = None,
    min_opacity: float = 0.5,
    depth: str = "expected",
    crop: Sequence[float] | None = None,
    faces: int | None = None,
    min_component: float = 0.01,
    truncation_voxels: float = 4.0,
    device: str | None = None,
    memory_limit: int | None = None,
    progress: bool = True,
    views: list[dict[str, torch.Tensor]] | None = None,
) -> dict[str, Any]:
    """Write the mesh of a trained scene run (module docstring) to ``out``; returns a summary.

    ``views``: :func:`~pointfield.geometry.clouds.render_views` of the cameras of ``path`` and
    ``frames``, when the caller has them already (as for :func:`~pointfield.geometry.export_cloud`).

    ``method``: "sdf" (the default for an sdf run; ``report`` in the summary says how closed the
    mesh is) meshes its zero level set (:mod:`~pointfield.geometry.sdf_mesh`) and ignores the
    rendering options as "density" does; "tsdf" (the default for any other run) fuses rendered
    depth; "density" meshes a bounded field run's
    density at ``threshold`` (default :func:`~pointfield.geometry.density.default_threshold`),
    and ignores the rendering options but ``frames``, the training views that judge what was
    seen (:func:`~pointfield.geometry.density.mesh_from_density`). ``depth``: "expected" or "median", as for
    :func:`~pointfield.geometry.export_cloud`. Raises :class:`PointfieldError` for a run that is not a scene run
    (or, for "density", not a bounded field run), a grid too large for ``memory_limit`` bytes
    (default: half the machine's memory; the message says how much it would need and what
    resolution fits), and a result with no surface.
    """
    from pointfield.fields.scene_box import scene_bounds

    out = Path(out)
    if out.suffix.lower() not in MESH_SUFFIXES:
        raise PointfieldError(f"{out}: a mesh is written as {', '.join(MESH_SUFFIXES)}")
    if method is not None and method not in MESH_METHODS:
        raise PointfieldError(f"the mesh method must be one of {', '.join(MESH_METHODS)}, got {method!r}")
    scene_run = open_scene_run(run, device)
    if method is None:
        method = "sdf" if getattr(scene_run, "config", {}).get("model") == "sdf" else "tsdf"
    if method != "density" and threshold is not None:
        raise PointfieldError(f"a density threshold is for --method density; {method.upper()} meshes have none")
    if method == "sdf":
        return _export_sdf_mesh(scene_run, out, resolution=resolution, crop=crop, faces=faces,
                                memory_limit=memory_limit if memory_limit is not None else _default_memory_limit())
    if method == "density":
        return _export_density_mesh(
            scene_run, out, resolution=resolution, threshold=threshold, crop=crop, faces=faces, frames=frames,
            min_component=min_component,
            memory_limit=memory_limit if memory_limit is not None else _default_memory_limit(), progress=progress,
        )
    cameras = cameras_of(scene_run, path, frames)
    scene = scene_run.scene
    if crop is not None:
        low, high = np.asarray(crop[:3], np.float64), np.asarray(crop[3:], np.float64)
        box_source = "crop"
    else:
        (low, high), unbounded = scene_bounds(scene)
        box_source = "region of interest of an unbounded capture" if unbounded else "scene box"
        # A surface on the box's faces (an object's tight aabb) needs voxels outside it too.
        pad = (truncation_voxels + 2) * float(np.max(np.subtract(high, low))) / resolution
        low, high = np.subtract(low, pad), np.add(high, pad)
    volume = TSDFVolume.create(
        low, high, resolution, truncation_voxels=truncation_voxels, device=scene_run.device,
        memory_limit=memory_limit if memory_limit is not None else _default_memory_limit(),
    )
    depth_maps = rendered_depth_maps(scene_run, cameras, min_opacity, progress, views, depth)
    fuse(volume, depth_maps, cameras)
    mesh = mesh_from_volume(volume, min_component)
    fused_faces = len(mesh.faces)
    if faces is not None:
        mesh = decimate(mesh, faces)
    write_mesh(out, mesh)
    return {
        "out": str(out), "vertices": len(mesh.points), "faces": len(mesh.faces), "fused_faces": fused_faces,
        "views": len(cameras), "grid": list(volume.shape), "voxel": volume.voxel, "box": [list(low), list(high)],
        "box_source": box_source,
    }


def _export_density_mesh(scene_run, out: Path, *, resolution, threshold, crop, faces, frames, min_component,
                         memory_limit, progress) -> dict[str, Any]:
    """``export_mesh`` with ``method="density"``: the density mesh, floaters dropped, decimated, written."""
    _, field_box = density_field(scene_run)
    if crop is not None:
        low, high = np.asarray(crop[:3], np.float64), np.asarray(crop[3:], np.float64)
        box_source = "crop"
    else:
        (low, high), box_source = field_box, "field's box"
    threshold = default_threshold(field_box) if threshold is None else threshold
    shape, voxel = grid_shape(low, high, resolution)
    mesh = mesh_from_density(scene_run, low, high, resolution, threshold, frames=frames, memory_limit=memory_limit,
                             progress=progress)
    mesh = drop_small_components(mesh, min_component)
    meshed_faces = len(mesh.faces)
    if faces is not None:
        mesh = decimate(mesh, faces)
    write_mesh(out, mesh)
    return {
        "out": str(out), "vertices": len(mesh.points), "faces": len(mesh.faces), "meshed_faces": meshed_faces,
        "threshold": float(threshold), "grid": list(shape), "voxel": voxel, "box": [list(low), list(high)],
        "box_source": box_source,
    }


def _export_sdf_mesh(scene_run, out: Path, *, resolution, crop, faces, memory_limit) -> dict[str, Any]:
    """``export_mesh`` with ``method="sdf"``: the zero level set, its largest piece, decimated, written."""
    low, high, box_source = (None, None, "field's box") if crop is None else (crop[:3], crop[3:], "crop")
    mesh, report = mesh_from_sdf(scene_run, low, high, resolution, memory_limit=memory_limit)
    meshed_faces = len(mesh.faces)
    if faces is not None:
        mesh = decimate(mesh, faces)
    write_mesh(out, mesh)
    box = scene_run.module.box.tolist() if crop is None else [list(crop[:3]), list(crop[3:])]
    return {
        "out": str(out), "vertices": len(mesh.points), "faces": len(mesh.faces), "meshed_faces": meshed_faces,
        "grid": report["grid"], "voxel": report["voxel"], "box": box, "box_source": box_source,
        "pieces": report["pieces"], "openness": report["openness"], "watertight": report["watertight"],
    }


def _between_observed(vertices: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``(V,)`` True where both voxels of a vertex's grid edge were observed.

    A marching-cubes vertex lies on the edge between two voxels; one of them unobserved (F = 1 as
    initialised, e.g. inside a solid beyond the truncation) makes a false surface there.
    """
    low = np.floor(vertices).astype(np.int64)
    high = np.ceil(vertices).astype(np.int64)
    for corner in (low, high):
        for axis, size in enumerate(observed.shape):
            np.clip(corner[:, axis], 0, size - 1, out=corner[:, axis])
    return observed[tuple(low.T)] & observed[tuple(high.T)]


def _compact(mesh: Mesh, faces: np.ndarray) -> Mesh:
    used, inverse = np.unique(faces.reshape(-1), return_inverse=True)
    fields = {name: values[used] for name, values in mesh.fields.items()}
    return Mesh(mesh.points[used], fields, faces=inverse.reshape(faces.shape).astype(np.int64))


def _as_uint8(colours: np.ndarray) -> np.ndarray:
    return (np.clip(colours, 0, 1) * 255).round().astype(np.uint8)


def _default_memory_limit() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") * DEFAULT_MEMORY_FRACTION)
    except (ValueError, OSError, AttributeError):
        return 8 << 30
