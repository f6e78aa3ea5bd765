"""OBJ, STL and GLB / glTF meshes, read (and OBJ, STL, GLB written) through trimesh.

These are the mesh formats of games, printers and the web, and the ones ``nerf export --mesh``
and ``splat export --mesh`` write (OBJ, GLB): what pointfield writes, it reads back. Each is one
:class:`Format` of the registry, so ``pointfield.read``, ``cloud info / render / convert`` and
``pointfield view`` take them as they take PLY and OFF meshes.

How a file maps onto a :class:`Mesh`: trimesh's vertices become ``points`` (float64), its
triangles ``faces`` (``(F, 3)`` int64; trimesh triangulates polygons), and per-vertex colours,
where the file has them, the ``colors`` field (uint8 RGBA as trimesh gives them, alpha dropped
when every vertex is opaque). A GLB / glTF scene of several meshes is flattened into one with
every node's transform applied. Vertices are kept as the file lists them (``process=False``:
nothing merged or reordered). A file with vertices but no faces (an OBJ of ``v`` lines) reads
as a :class:`PointCloud`.

A glTF ``.gltf`` keeps its buffers in files beside it, which must be there. Errors of any kind
trimesh raises for a malformed file become a FormatError naming the file.
"""

from __future__ import annotations

import warnings
from functools import partial
from pathlib import Path

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.ptx import _colors_0_to_255
from pointfield.clouds.formats.registry import Format, register
from pointfield.clouds.mesh import Mesh
from pointfield.errors import FormatError


def looks_like_glb(head: bytes) -> bool:
    """A binary glTF starts with the magic ``glTF`` (then its version, 2)."""
    return head[:4] == b"glTF"


def read_mesh(path: Path) -> Mesh | PointCloud:
    """Read ``path`` with trimesh (module docstring)."""
    import trimesh

    try:
        loaded = trimesh.load(path, file_type=_file_type(path), process=False)
        if _file_type(path) == "stl" and isinstance(loaded, trimesh.Trimesh):
            loaded.merge_vertices()  # STL repeats each triangle's corners: shared vertices come back shared
        if isinstance(loaded, trimesh.Scene):
            geometry = [g for g in loaded.dump() if hasattr(g, "vertices")]
            meshes = [g for g in geometry if isinstance(g, trimesh.Trimesh)]
            loaded = trimesh.util.concatenate(meshes) if meshes else (geometry[0] if geometry else None)
        vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
        faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    except FormatError:
        raise
    except Exception as error:  # noqa: BLE001  (trimesh raises many types for malformed files)
        raise FormatError(path, f"not a readable {path.suffix.lstrip('.').upper() or 'mesh'} file ({error})") from None
    if loaded is None or len(vertices) == 0:
        raise FormatError(path, "the file holds no vertices")
    fields = {}
    colours = _vertex_colours(loaded, len(vertices))
    if colours is not None:
        fields["colors"] = colours
    metadata = {"encoding": _encoding(path)}
    if len(faces) == 0:
        return PointCloud(vertices, fields, None, metadata)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise FormatError(path, f"faces index vertices outside 0..{len(vertices) - 1}")
    return Mesh(vertices, fields, None, metadata, faces=faces)


def write_mesh(path: Path, cloud: PointCloud, encoding: str | None = None, *, file_type: str,
               keeps_colours: bool = True) -> None:
    """Write a Mesh's vertices, triangles and (where ``keeps_colours``) ``colors`` with trimesh as
    ``file_type``; every other field, and colours the format cannot keep, is named in one warning.

    Colours are written as uint8 as PTX writes them (uint16 / 257, floats in [0, 1] x 255, rounded;
    the change is named in the warning). The registry refuses a cloud without faces
    (``Format.needs_faces``) before this is called.
    """
    import trimesh

    if path.suffix.lower() == ".gltf":
        raise FormatError(path, "pointfield writes glTF as one .glb file (its buffers inside); name it .glb")
    notes = []
    colours = cloud.fields.get("colors") if keeps_colours else None
    if colours is not None:
        colours = np.asarray(colours)
        colours = _colors_0_to_255(colours, notes) if colours.ndim == 2 and colours.shape[1] in (3, 4) else None
    kept = {"colors"} if colours is not None else set()
    dropped = sorted(name for name in cloud.fields if name not in kept)
    label = file_type.upper()
    if dropped:
        kept_here = "vertices, triangles and colours" if keeps_colours else "vertices and triangles"
        notes.append(f"keeps {kept_here}; not written: {', '.join(dropped)}")
    if notes:
        warnings.warn(f"{label}: {'; '.join(notes)}", stacklevel=2)
    shape = trimesh.Trimesh(np.asarray(cloud.points, np.float64), cloud.triangles(), vertex_colors=colours,
                            process=False)
    shape.export(path, file_type=file_type)


def _vertex_colours(loaded, count: int) -> np.ndarray | None:
    visual = getattr(loaded, "visual", None)
    if visual is None or getattr(visual, "kind", None) != "vertex":
        return None
    colours = np.asarray(visual.vertex_colors, np.uint8)
    if colours.shape != (count, 4):
        return None
    return colours[:, :3] if np.all(colours[:, 3] == 255) else colours


def _file_type(path: Path) -> str:
    """trimesh's name for the file's type: from its signature for GLB (any name), else its suffix."""
    with open(path, "rb") as file:
        if looks_like_glb(file.read(4)):
            return "glb"
    suffix = path.suffix.lower()
    return {".gltf": "gltf", ".glb": "glb", ".stl": "stl"}.get(suffix, "obj")


def _encoding(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix == ".stl":
        with open(path, "rb") as file:  # an ascii STL starts "solid"; a binary one has an 80-byte header
            return "ascii" if file.read(5).lower() == b"solid" else "binary"
    return "binary" if _file_type(path) == "glb" else {".gltf": "json", ".obj": "ascii"}.get(suffix, "binary")


def _mesh_format(name: str, description: str, suffixes: tuple[str, ...], encoding: str, write_as: str,
                 keeps_colours: bool, signature=None) -> Format:
    """One trimesh format: the same reader for all; the writer told trimesh's file type and whether
    the format keeps vertex colours. Each holds meshes only (a cloud without faces is refused)."""
    return Format(name=name, description=description, suffixes=suffixes, read=read_mesh,
                  write=partial(write_mesh, file_type=write_as, keeps_colours=keeps_colours), encodings=(encoding,),
                  signature=signature, holds_faces=True, needs_faces=True)


register(_mesh_format("gltf", "glTF 2.0 meshes, .glb (binary, one file) or .gltf (its buffers beside it), through "
                      "trimesh", (".glb", ".gltf"), "binary", "glb", True, looks_like_glb))
register(_mesh_format("obj", "Wavefront OBJ meshes, through trimesh", (".obj",), "ascii", "obj", True))
register(_mesh_format("stl", "STL meshes (binary or ascii), through trimesh; STL has no vertex colours", (".stl",),
                      "binary", "stl", False))
