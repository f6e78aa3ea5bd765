"""The mesh of a neural SDF run (``--model sdf``): its zero level set, one closed surface (``--method sdf``).

::

    mesh, report = mesh_from_sdf(load_run("runs/cube-sdf"), resolution=256)   # or: nerf export RUN --mesh cube.ply

1. Sample the field's signed distance at the nodes ``low + ijk * voxel`` of a grid over its box
   (``resolution`` voxels along the longest side), without gradients, a slab at a time, on the
   run's device, into an :class:`~pointfield.volumes.sdf.SDFGrid`.
2. Pad the grid with one node of distance ``+voxel`` on every side: nothing is inside beyond the
   box, so a surface the box cuts is closed there instead of left open.
3. Marching cubes at the zero level (:meth:`SDFGrid.to_mesh <pointfield.volumes.sdf.SDFGrid.to_mesh>`),
   faces facing out.
4. Keep the largest connected piece (stray bubbles of negative distance in space no view
   constrains are dropped), and report how closed the result is
   (:func:`~pointfield.volumes.voxels.mesh_openness`: watertight when every edge is shared by
   exactly two faces).
5. Colour each vertex with what a camera looking at it along its inward normal sees
   (:func:`~pointfield.geometry.density.surface_colours`, as density meshes are coloured), the
   normal being the field's own gradient there (:func:`outward_normals`).

No rendered depth is fused and no density threshold chosen: the surface is where the field says
it is, and it has no holes where views disagree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from pointfield.clouds.mesh import Mesh
from pointfield.errors import PointfieldError
from pointfield.fields.run import FieldRun
from pointfield.fields.sdf import NeuralSDF
from pointfield.geometry.density import COLOUR_RAY_VOXELS, DENSITY_CHUNK, surface_colours
from pointfield.volumes.sdf import SDFGrid
from pointfield.volumes.voxels import mesh_openness

BYTES_PER_NODE = 4
"""The float32 distance grid marching cubes reads (its output grows with the surface only)."""


def sdf_model_of(scene_run: Any) -> NeuralSDF:
    """The :class:`~pointfield.fields.sdf.NeuralSDF` of an ``sdf`` run; :class:`PointfieldError` for any other run."""
    model = getattr(scene_run, "module", None) if isinstance(scene_run, FieldRun) else None
    if not isinstance(model, NeuralSDF):
        raise PointfieldError(f"{scene_run.path}: --method sdf needs a run of nerf train --model sdf; use --method "
                              "tsdf (any run) or density (a field of an object in a box)")
    return model


@torch.no_grad()
def sample_sdf(model: NeuralSDF, low: Sequence[float], voxel: float, shape: tuple[int, int, int],
               chunk: int = DENSITY_CHUNK) -> SDFGrid:
    """The field's signed distance (world units) at the nodes ``low + ijk * voxel`` of a ``shape`` grid, padded.

    The grid returned has one more node on every side, at ``+voxel`` (module docstring, step 2),
    so its origin is ``low - voxel`` and its shape ``shape + 2``. Evaluated an x-slab at a time.
    """
    size_x, size_y, size_z = shape
    values = np.full((size_x + 2, size_y + 2, size_z + 2), voxel, np.float32)
    device = model.box.device
    low_tensor = torch.as_tensor(np.asarray(low, np.float64), dtype=torch.float32, device=device)
    j, k = torch.meshgrid(torch.arange(size_y, device=device), torch.arange(size_z, device=device), indexing="ij")
    slab = torch.stack([torch.zeros_like(j), j, k], dim=-1).reshape(-1, 3).float()
    for i in range(size_x):
        slab[:, 0] = i
        points = low_tensor + slab * voxel
        distances = torch.cat([model.sdf_at(part) for part in points.split(chunk)])
        values[i + 1, 1:-1, 1:-1] = distances.reshape(size_y, size_z).float().cpu().numpy()
    return SDFGrid(values, np.asarray(low, np.float64) - voxel, voxel)


def outward_normals(model: NeuralSDF, points: np.ndarray, chunk: int = DENSITY_CHUNK) -> np.ndarray:
    """``(V, 3)`` float64: the field's own outward normals ``grad f / |grad f|`` at world ``points`` ``(V, 3)``.

    The colour ray must enter the surface: NeuS's alpha makes a ray that leaves it see nothing.
    """
    device = model.box.device
    normals = []
    for part in torch.as_tensor(points, dtype=torch.float32).split(chunk):
        _, gradient, _ = model.sdf_and_gradient(model.to_box_units(part.to(device)), create_graph=False)
        normals.append(torch.nn.functional.normalize(gradient, dim=-1).cpu())
    return torch.cat(normals).double().numpy() if normals else np.zeros((0, 3))


def largest_component(mesh: Mesh) -> tuple[Mesh, int]:
    """The connected piece of ``mesh`` with the most faces, and how many pieces there were."""
    from pointfield.geometry.meshes import _compact, face_components  # here: meshes imports this module

    face_labels = face_components(mesh)
    sizes = np.bincount(face_labels)
    return _compact(mesh, mesh.faces[face_labels == sizes.argmax()]), int(np.count_nonzero(sizes))


def mesh_from_sdf(
    scene_run: Any,
    low: Sequence[float] | None = None,
    high: Sequence[float] | None = None,
    resolution: int = 256,
    *,
    memory_limit: int | None = None,
) -> tuple[Mesh, dict[str, Any]]:
    """The zero level set of an ``sdf`` run over a box (module docstring): the mesh and a report.

    ``low``, ``high``: the box's ``(3,)`` corners (default: the field's own box); ``resolution``
    voxels along its longest side. Vertices are float64 world points with uint8 ``colors``;
    faces face out. The report: ``grid`` (nodes per axis, padding excluded), ``voxel``,
    ``pieces`` (connected pieces before the largest was kept), ``openness`` and ``watertight``.
    Raises :class:`PointfieldError` for a run that is not an sdf run, a grid larger than
    ``memory_limit`` bytes and a field that has no zero crossing in the box.
    """
    model = sdf_model_of(scene_run)
    box = model.box.detach().cpu().double().numpy()
    low = box[0] if low is None else np.asarray(low, np.float64)
    high = box[1] if high is None else np.asarray(high, np.float64)
    if resolution < 2 or not bool(np.all(high > low)):
        raise PointfieldError(f"an SDF mesh needs a resolution of 2 or more and a box with min < max, got "
                              f"{resolution} and {low.tolist()} to {high.tolist()}")
    voxel = float(np.max(high - low)) / resolution
    shape = tuple(int(n) for n in np.floor((high - low) / voxel + 1e-9).astype(np.int64) + 1)
    needed = int(np.prod([size + 2 for size in shape])) * BYTES_PER_NODE
    if memory_limit is not None and needed > memory_limit:
        fits = int(resolution * (memory_limit / needed) ** (1 / 3))
        raise PointfieldError(f"a {resolution}^3 SDF grid needs {needed / 2**30:.1f} GiB, more than the "
                              f"{memory_limit / 2**30:.1f} GiB allowed; pass --resolution {fits} or less")
    grid = sample_sdf(model, low, voxel, shape)
    if not grid.values.min() < 0:
        raise PointfieldError(f"{scene_run.path}: the signed distance is positive everywhere in the box (its "
                              f"least value is {grid.values.min():.4g}); there is no surface to mesh")
    mesh = grid.to_mesh(0.0)
    mesh, pieces = largest_component(mesh)
    del mesh.fields["normals"]
    mesh.fields["colors"] = surface_colours(model, mesh.points, outward_normals(model, mesh.points),
                                            COLOUR_RAY_VOXELS * voxel, model.box.device)
    openness = mesh_openness(mesh)
    report = {"grid": list(shape), "voxel": voxel, "pieces": pieces, "openness": openness,
              "watertight": openness["boundary"] == 0 and openness["nonmanifold"] == 0}
    return mesh, report
