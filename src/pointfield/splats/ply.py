"""The standard splat ``.ply`` layout, read and written exactly.

Every splat viewer and trainer (the original 3D Gaussian splatting code, gsplat, nerfstudio,
SuperSplat, ...) reads one ``binary_little_endian`` PLY whose ``vertex`` element has float32
properties, in this order::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3(K-1)-1}  opacity
    scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

``nx ny nz`` are unused (zeros). ``f_dc_*`` is the degree-0 SH coefficient of R, G, B;
``f_rest_*`` the higher ones, **channel-major**: all K-1 red coefficients, then green, then
blue (``f_rest[c * (K-1) + k]`` is coefficient k+1 of channel c). ``opacity`` is the logit,
``scale_*`` the log standard deviations, ``rot_*`` the quaternion w x y z (not normalised).
These are exactly :class:`~pointfield.splats.gaussians.Gaussians`' parameters, so writing
then reading returns every attribute bit for bit.

How the splats were trained to be drawn (:func:`~pointfield.splats.rasterizer.rasterizer_mode`: classic
or antialiased, and the screen dilation) travels in a header comment that other programs ignore,
``comment pointfield rasterizer antialiased=1 screen_dilation=0.1`` (:data:`MODE_COMMENT`). A file
without it is drawn as the original 3D Gaussian splatting code draws: classic, 0.3 px^2.

The file goes through pointfield's PLY reader and writer (:func:`pointfield.read` /
:func:`pointfield.write`), so malformed files raise :class:`~pointfield.errors.FormatError`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.clouds import read as read_cloud
from pointfield.clouds import write as write_cloud
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.ply import SPLAT_PROPERTIES
from pointfield.clouds.formats.ply.header import HEADER_LIMIT, parse_header
from pointfield.errors import FormatError
from pointfield.splats.gaussians import Gaussians
from pointfield.splats.rasterizer import rasterizer_mode

MODE_COMMENT = "pointfield rasterizer"
"""The start of the header comment that records the rasterizer mode (module doc)."""


def read_splats(path: str | os.PathLike[str], dtype: torch.dtype = torch.float32) -> Gaussians:
    """Read a standard splat ``.ply`` into :class:`Gaussians` (all SH degrees active)."""
    path = Path(path)
    cloud = read_cloud(path, format="ply")
    if not isinstance(cloud, PointCloud):
        raise FormatError(path, "expected a PLY with x, y, z vertex properties (a splat file)")
    fields = cloud.fields
    count = len(cloud.points)
    rest_names = sorted((name for name in fields if name.startswith("f_rest_")), key=lambda n: int(n[7:]) if n[7:].isdigit() else -1)
    required = list(SPLAT_PROPERTIES)
    missing = [name for name in required if name not in fields]
    if missing:
        raise FormatError(path, f"not a splat file: vertex properties {', '.join(missing)} are missing "
                                f"(expected x y z f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3)")
    expected_rest = [f"f_rest_{i}" for i in range(len(rest_names))]
    per_channel = len(rest_names) // 3 + 1
    if rest_names != expected_rest or len(rest_names) % 3 or per_channel not in (1, 4, 9, 16):
        raise FormatError(path, f"{len(rest_names)} f_rest_* properties: expected f_rest_0 .. f_rest_N-1 "
                                f"with N = 0, 9, 24 or 45 (SH degree 0 to 3)")
    for name in required + rest_names:
        if fields[name].ndim != 1:
            raise FormatError(path, f"property {name} must be a scalar per vertex")

    def column(*names: str) -> torch.Tensor:
        if not names:
            return torch.zeros(count, 0, dtype=dtype)
        stacked = np.stack([np.asarray(fields[name]) for name in names], axis=1)
        return torch.as_tensor(stacked).to(dtype)

    rest = column(*rest_names).reshape(count, 3, per_channel - 1).transpose(1, 2)
    return Gaussians(
        means=torch.as_tensor(np.asarray(cloud.points)).to(dtype),
        quats=column("rot_0", "rot_1", "rot_2", "rot_3"),
        log_scales=column("scale_0", "scale_1", "scale_2"),
        opacity_logits=column("opacity")[:, 0],
        sh_dc=column("f_dc_0", "f_dc_1", "f_dc_2")[:, None, :],
        sh_rest=rest.contiguous(),
    )


def splats_to_cloud(gaussians: Gaussians) -> PointCloud:
    """The splat ``.ply`` layout as a :class:`PointCloud` (float32 fields, in file order)."""
    count = len(gaussians)

    def as_numpy(tensor: torch.Tensor) -> np.ndarray:
        return tensor.detach().cpu().to(torch.float32).numpy()

    rest = as_numpy(gaussians.sh_rest.transpose(1, 2).reshape(count, -1))
    fields: dict[str, np.ndarray] = {"normals": np.zeros((count, 3), np.float32)}
    dc = as_numpy(gaussians.sh_dc[:, 0, :])
    for channel in range(3):
        fields[f"f_dc_{channel}"] = np.ascontiguousarray(dc[:, channel])
    for index in range(rest.shape[1]):
        fields[f"f_rest_{index}"] = np.ascontiguousarray(rest[:, index])
    fields["opacity"] = as_numpy(gaussians.opacity_logits)
    scales = as_numpy(gaussians.log_scales)
    for axis in range(3):
        fields[f"scale_{axis}"] = np.ascontiguousarray(scales[:, axis])
    quats = as_numpy(gaussians.quats)
    for component in range(4):
        fields[f"rot_{component}"] = np.ascontiguousarray(quats[:, component])
    return PointCloud(as_numpy(gaussians.means), fields)


def write_splats(path: str | os.PathLike[str], gaussians: Gaussians, mode: dict[str, Any] | None = None) -> None:
    """Write ``gaussians`` as a standard ``binary_little_endian`` splat ``.ply`` (atomically).

    ``mode``: ``{"antialiased": bool, "screen_dilation": float}``, written as the header comment
    of the module doc; None writes no comment (the file stays byte for byte what 3DGS writes).
    """
    cloud = splats_to_cloud(gaussians)
    if mode is not None:
        comment = (f"{MODE_COMMENT} antialiased={int(bool(mode['antialiased']))} "
                   f"screen_dilation={float(mode['screen_dilation'])!r}")
        cloud.metadata["comments"] = [comment]
    write_cloud(Path(path), cloud, format="ply", encoding="binary_little_endian")


def read_splat_mode(path: str | os.PathLike[str]) -> dict[str, Any]:
    """How a splat ``.ply``'s splats are drawn: its header comment, else 3DGS's classic mode, 0.3 px^2.

    Returns the keyword arguments of the rasterizer (:func:`~pointfield.splats.rasterizer.rasterizer_mode`).
    """
    path = Path(path)
    with path.open("rb") as file:
        header = parse_header(path, file.read(HEADER_LIMIT))
    recorded: dict[str, Any] = {}
    for comment in header.comments:
        if not comment.startswith(MODE_COMMENT + " "):
            continue
        settings = dict(item.partition("=")[::2] for item in comment[len(MODE_COMMENT):].split())
        try:
            antialiased, dilation = settings["antialiased"], float(settings["screen_dilation"])
            if antialiased not in ("0", "1") or not math.isfinite(dilation) or dilation <= 0:
                raise ValueError
        except (KeyError, ValueError):
            raise FormatError(path, f"header comment {comment[:80]!r}: expected '{MODE_COMMENT} antialiased=0|1 "
                                    f"screen_dilation=<a positive number of px^2>'") from None
        recorded = {"antialiased": antialiased == "1", "screen_dilation": dilation}
    return rasterizer_mode(recorded)
