"""What a point-cloud file holds, as a JSON-ready dict and as aligned text.

:func:`describe` is the Python form of ``pointfield cloud info FILE``; :func:`format_description`
prints its result the way the command does without ``--json``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import Records
from pointfield.clouds.formats import read
from pointfield.clouds.mesh import Mesh

# Metadata values longer than this (VLR payloads, embedded images) are left out of the summary.
MAX_METADATA_ITEMS = 256
MAX_METADATA_STRING = 4096


def describe(path: str | os.PathLike[str], **read_options: Any) -> dict[str, Any]:
    """Read ``path`` and summarise it in a dict that ``json.dumps`` accepts.

    Keys:

    =========================  ==================================================================
    ``path``, ``bytes``        the file and its size
    ``format``, ``encoding``   as the reader found them (``"pcd"``, ``"binary_compressed"``)
    ``kind``                   ``"cloud"``, ``"mesh"`` or ``"records"`` (a file without x/y/z)
    ``points``                 points stored, NaN points included (records: the record count)
    ``nan_points``             points with a NaN coordinate
    ``points_dtype``           ``"float32"`` or ``"float64"`` (None for records)
    ``fields``                 name -> dtype string, e.g. ``{"colors": "uint8"}``
    ``field_components``       name -> components per point, e.g. ``{"colors": 3}``
    ``bounds``                 ``{"min": [x, y, z], "max": [x, y, z]}`` of the finite points,
                               None when there are none
    ``organised``              ``[H, W]`` for organised clouds, else None
    ``faces``                  faces of a mesh, 0 otherwise
    ``face_fields``            per-face fields of a mesh, name -> dtype string
    ``face_field_components``  name -> components per face
    ``metadata``               the rest of what the file says (viewpoint, LAS scales, comments),
                               keeping only JSON-representable values of modest size
    =========================  ==================================================================

    ``read_options`` go to :func:`pointfield.read` (e.g. ``columns=5`` for a nuScenes scan).
    """
    path = Path(path)
    cloud = read(path, **read_options)
    metadata = {k: v for k, v in cloud.metadata.items() if k not in ("format", "encoding")}
    info: dict[str, Any] = {
        "path": str(path),
        "bytes": path.stat().st_size,
        "format": cloud.metadata.get("format"),
        "encoding": cloud.metadata.get("encoding"),
        "kind": "records"
        if isinstance(cloud, Records)
        else "mesh"
        if isinstance(cloud, Mesh)
        else "cloud",
        "points": len(cloud),
        "nan_points": 0,
        "points_dtype": None,
        "fields": {name: str(values.dtype) for name, values in cloud.fields.items()},
        "field_components": {name: _components(values) for name, values in cloud.fields.items()},
        "bounds": None,
        "organised": None,
        "faces": 0,
        "face_fields": {},
        "face_field_components": {},
        "metadata": _json_safe(metadata),
    }
    if isinstance(cloud, Records):
        return info
    info["nan_points"] = cloud.nan_count
    info["points_dtype"] = str(cloud.points.dtype)
    low, high = cloud.bounds()
    if np.isfinite(low).all():
        info["bounds"] = {"min": [float(v) for v in low], "max": [float(v) for v in high]}
    if cloud.shape is not None:
        info["organised"] = list(cloud.shape)
    if isinstance(cloud, Mesh):
        info["faces"] = len(cloud.faces)
        info["face_fields"] = {name: str(v.dtype) for name, v in cloud.face_fields.items()}
        info["face_field_components"] = {n: _components(v) for n, v in cloud.face_fields.items()}
    return info


def format_description(info: dict[str, Any]) -> str:
    """The dict of :func:`describe` as aligned, human-readable lines.

    Example::

        file        pcd/pcl_table_scene_mug_organized.pcd (1,726,160 bytes)
        format      pcd, binary_compressed
        points      307,200 float32, 97,920 NaN, organised 480 x 640
        bounds      x -0.45643 .. 0.71518   y -0.51074 .. 0.17923   z 0.69001 .. 2.5927
        fields      colors  uint8 x 4
    """
    rows: list[tuple[str, str]] = [
        ("file", f"{info['path']} ({info['bytes']:,} bytes)"),
        ("format", format_and_encoding(info["format"], info["encoding"])),
    ]
    if info["kind"] == "records":
        rows.append(("records", f"{info['points']:,} (no x/y/z coordinates)"))
    else:
        points = [f"{info['points']:,} {info['points_dtype']}"]
        if info["nan_points"]:
            points.append(f"{info['nan_points']:,} NaN")
        if info["organised"]:
            points.append("organised {} x {}".format(*info["organised"]))
        rows.append(("points", ", ".join(points)))
        if info["kind"] == "mesh":
            rows.append(("faces", f"{info['faces']:,}"))
        rows.append(("bounds", _bounds_text(info["bounds"], info["points_dtype"])))
    rows += _name_rows("fields", info["fields"], info["field_components"])
    if info["face_fields"]:
        rows += _name_rows("face fields", info["face_fields"], info["face_field_components"])
    for i, (key, value) in enumerate(info["metadata"].items()):
        rows.append(("metadata" if i == 0 else "", f"{key}: {_short(value)}"))
    width = max(len(label) for label, _ in rows) + 2
    return "\n".join(f"{label:<{width}}{text}".rstrip() for label, text in rows)


def _name_rows(
    label: str, dtypes: dict[str, str], components: dict[str, int]
) -> list[tuple[str, str]]:
    if not dtypes:
        return [(label, "none")]
    name_width = max(len(name) for name in dtypes) + 2
    rows = []
    for i, (name, dtype) in enumerate(dtypes.items()):
        count = components.get(name, 1)
        rows.append(
            (
                label if i == 0 else "",
                f"{name:<{name_width}}{dtype}" + (f" x {count}" if count != 1 else ""),
            )
        )
    return rows


def _components(values: np.ndarray) -> int:
    """Values per point: 1 for ``(N,)``, K for ``(N, K)``, the product for deeper shapes."""
    return int(np.prod(values.shape[1:], dtype=np.int64))


def _bounds_text(bounds: dict[str, list[float]] | None, dtype: str) -> str:
    if bounds is None:
        return "none (no finite point)"
    return "   ".join(
        f"{axis} {_number(low, dtype)} .. {_number(high, dtype)}"
        for axis, low, high in zip("xyz", bounds["min"], bounds["max"], strict=True)
    )


def format_and_encoding(name: str | None, encoding: str | None) -> str:
    """``"ply, ascii"``, ``"las, laz"``; the encoding alone is left out where it repeats the
    format's name (``"las"``, not ``"las las"``)."""
    if encoding and encoding != name:
        return f"{name}, {encoding}"
    return str(name)


def _number(value: float, dtype: str) -> str:
    """Enough significant digits for the points' precision, and no float noise beyond it."""
    return f"{value:.{7 if dtype == 'float32' else 10}g}"


def _short(value: Any) -> str:
    text = str(value)
    return text if len(text) <= 100 else text[:97] + "..."


def _json_safe(value: Any) -> Any:
    """``value`` with numpy types made plain, and what JSON cannot hold (or is huge) left out.

    Returns the value itself for str / bool / int / finite float / None, a list or dict of safe
    values (unsafe members dropped), or :data:`_OMIT` when nothing sensible remains. Non-finite
    floats become None, as JSON has no NaN.
    """
    if isinstance(value, dict):
        safe = {str(k): _json_safe(v) for k, v in list(value.items())[:MAX_METADATA_ITEMS]}
        return {k: v for k, v in safe.items() if v is not _OMIT}
    if isinstance(value, np.ndarray):
        if value.size > MAX_METADATA_ITEMS or value.dtype.kind not in "biuf":
            return _OMIT
        return _json_safe(value.tolist())
    if isinstance(value, (list, tuple)):
        if len(value) > MAX_METADATA_ITEMS:
            return _OMIT
        safe_items = [_json_safe(v) for v in value]
        return [v for v in safe_items if v is not _OMIT]
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str):
        return value if len(value) <= MAX_METADATA_STRING else _OMIT
    return _OMIT


_OMIT = object()  # marks a value _json_safe leaves out
