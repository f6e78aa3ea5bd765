"""Voxel grid files: Patrick Min's ``.binvox``, MagicaVoxel's ``.vox``, and NPZ; OctoMap's ``.bt`` is read too.

``.binvox`` (binvox 1, as binvox and binvox-rw-py write it) is a text header then run-length data::

    #binvox 1
    dim 32 32 32            <- voxels per axis (binvox itself writes cubes)
    translate -0.5 -0.5 -0.5
    scale 1.0               <- the cube's side: a voxel is scale / dim
    data
    <bytes>                 <- pairs (value 0 or 1, run length 1..255), voxel index
                               x * (dim_z * dim_y) + z * dim_y + y: y fastest, then z, then x

Voxel ``(x, y, z)``'s centre is ``translate + (xyz + 0.5) * scale / dim`` (binvox-rw-py's
convention), so a grid's ``origin`` is ``translate`` and its voxel ``size`` is ``scale / dim``;
the runs must cover exactly ``dim^3`` voxels. Only occupancy is stored: fields are not written.

``.vox`` (MagicaVoxel, version 150/200) is RIFF-like: ``"VOX "``, a version, then a ``MAIN`` chunk
whose children are ``SIZE`` (model size x y z, int32) and ``XYZI`` (a count, then x y z and a
colour index, one byte each) per model, and ``RGBA`` (255 colours for indices 1..255). Every chunk
is its id, the bytes of its content and of its children (int32 little-endian each), then those.
A model holds at most 256 voxels per axis (its coordinates are bytes): a grid bigger than that is
refused with the voxel that fits (MagicaVoxel's scene graph of several models is not written; a
file with several models reads its first, with a warning). Colours are the ``colors`` field,
reduced to 255 by PIL's median cut where there are more; no origin or voxel size is stored, so a
``.vox`` reads back with origin 0 and voxel 1 (z is up in MagicaVoxel, as in the grid).

``.npz`` holds everything: ``coords``, ``origin``, ``size``, ``shape``, each field as
``field/<name>``, and ``__metadata__`` (JSON). Nothing is unpickled, and each member's size is
checked against the archive before it is read.

An OctoMap binary tree (``.bt``) reads as the grid of its occupied cells
(:func:`~pointfield.volumes.occupancy.read_octomap_grid`: pruned leaves expanded into their cells,
free ones skipped), so that ``cloud render`` and ``view`` draw an occupancy map; it is written by
:func:`~pointfield.volumes.occupancy.write_octomap`, from an ``OccupancyMap``, not from a grid.

Every reader checks the sizes a file declares against the bytes it has before allocating, and
raises :class:`~pointfield.errors.FormatError` naming the file. Writes are atomic.
"""

from __future__ import annotations

import json
import os
import struct
import warnings
import zipfile
from pathlib import Path

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.errors import FormatError
from pointfield.volumes.occupancy import OCTOMAP_MAGIC, READ_BYTES_PER_CELL, read_octomap_grid
from pointfield.volumes.voxels import VoxelGrid

SUFFIXES = (".binvox", ".vox", ".npz")
MAX_HEADER_BYTES = 4096
MAX_VOX_AXIS = 256
MAX_BINVOX_DIM = 1 << 14
"""Voxels per binvox axis read at most: 16384^3 is 4 * 10^12 voxels, past any real file."""
MAX_READ_VOXELS = 1 << 28
"""Occupied voxels a file may unpack to (6 GiB of coordinates): run-length data expands 127-fold."""
NPZ_MAX_EXPANSION = 1100
"""Deflate expands at most 1032-fold: a member claiming more bytes per compressed byte lies."""


def is_voxel_file(path: str | os.PathLike[str]) -> bool:
    """``.binvox``, ``.vox`` and ``.bt`` files, and ``.npz`` archives written by :func:`write_voxels` (by their
    members)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".binvox", ".vox", ".bt"):
        return True
    if suffix == ".npz" and path.is_file():
        try:
            with zipfile.ZipFile(path) as archive:
                names = set(archive.namelist())
        except (zipfile.BadZipFile, OSError):
            return False
        return {"coords.npy", "origin.npy", "size.npy"} <= names
    return False


def read_voxels(path: str | os.PathLike[str]) -> VoxelGrid:
    """Read a ``.binvox``, ``.vox``, voxel ``.npz`` or OctoMap ``.bt`` file (by its first bytes, else its suffix)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    with open(path, "rb") as file:
        head = file.read(len(OCTOMAP_MAGIC))
    if head.startswith(OCTOMAP_MAGIC):
        grid = read_octomap_grid(path, MAX_READ_VOXELS * READ_BYTES_PER_CELL,
                                 advice=f"pointfield reads at most {MAX_READ_VOXELS:,} voxels of a file")
    elif head.startswith(b"#binvox"):
        grid = read_binvox(path)
    elif head.startswith(b"VOX "):
        grid = read_vox(path)
    elif head.startswith(b"PK"):
        grid = read_npz(path)
    else:
        raise FormatError(path, f"not a voxel file: expected '#binvox', 'VOX ', an NPZ archive or an OctoMap tree, "
                          f"found {head[:8]!r}")
    grid.metadata.setdefault("path", str(path))
    return grid


def write_voxels(path: str | os.PathLike[str], grid: VoxelGrid) -> None:
    """Write ``grid`` atomically as ``.binvox``, ``.vox`` or ``.npz``, as the suffix says."""
    path = Path(path)
    writers = {".binvox": _write_binvox, ".vox": _write_vox, ".npz": _write_npz}
    suffix = path.suffix.lower()
    if suffix not in writers:
        raise FormatError(path, f"unknown voxel format {suffix!r}; expected one of {list(writers)}")
    with atomic_path(path) as tmp:
        writers[suffix](tmp, grid, path)


# -- binvox ---------------------------------------------------------------------------------


def read_binvox(path: Path) -> VoxelGrid:
    data = path.read_bytes()
    header_end = data.find(b"data\n", 0, MAX_HEADER_BYTES)
    if header_end < 0:
        raise FormatError(path, f"binvox header has no 'data' line in its first {MAX_HEADER_BYTES} bytes")
    lines = data[:header_end].decode("ascii", "replace").split("\n")
    if not lines[0].startswith("#binvox"):
        raise FormatError(path, f"expected '#binvox 1' on the first line, found {lines[0]!r}")
    fields: dict[str, list[str]] = {}
    for line in lines[1:]:
        words = line.split()
        if words:
            fields[words[0]] = words[1:]
    try:
        dims = [int(v) for v in fields["dim"]]
        translate = [float(v) for v in fields.get("translate", ["0", "0", "0"])]
        scale = float(fields.get("scale", ["1"])[0])
    except (KeyError, ValueError, IndexError):
        raise FormatError(path, "binvox header needs 'dim D H W' and numeric 'translate' and 'scale' lines") from None
    if len(dims) != 3 or len(translate) != 3 or min(dims) < 1 or max(dims) > MAX_BINVOX_DIM:
        raise FormatError(path, f"binvox 'dim' must be three sizes in 1..{MAX_BINVOX_DIM} and 'translate' three "
                          f"numbers, got dim {dims}, translate {translate}")
    if not (scale > 0 and np.isfinite(scale) and np.isfinite(translate).all()):
        raise FormatError(path, f"binvox 'scale' must be positive and 'translate' finite, got {scale}, {translate}")
    body = np.frombuffer(data, np.uint8, offset=header_end + len(b"data\n"))
    total = dims[0] * dims[1] * dims[2]
    # Each pair covers at most 255 voxels: a file too short for its dims is refused before decoding.
    if len(body) % 2:
        raise FormatError(path, f"binvox data has {len(body)} bytes; run-length pairs need an even number")
    values, lengths = body[0::2], body[1::2].astype(np.int64)
    covered = int(lengths.sum())
    if covered != total:
        raise FormatError(path, f"binvox runs cover {covered:,} voxels but 'dim {' '.join(map(str, dims))}' "
                          f"declares {total:,} (truncated or corrupt data)")
    if values.max(initial=0) > 1:
        raise FormatError(path, f"binvox run values must be 0 or 1, found {int(values.max())}")
    starts = np.cumsum(lengths) - lengths
    filled = values == 1
    if int(lengths[filled].sum()) > MAX_READ_VOXELS:
        raise FormatError(path, f"binvox data fills {int(lengths[filled].sum()):,} voxels, more than the "
                          f"{MAX_READ_VOXELS:,} pointfield reads")
    run_starts, run_lengths = starts[filled], lengths[filled]
    index = np.repeat(run_starts - (np.cumsum(run_lengths) - run_lengths), run_lengths) + np.arange(int(run_lengths.sum()))
    # index = x * (d1 * d2) + a1 * d2 + a2, with (a1, a2) = (z, y) in binvox-rw-py's reading.
    x, rest = np.divmod(index, dims[1] * dims[2])
    z, y = np.divmod(rest, dims[2])
    coords = np.stack([x, y, z], axis=1)
    size = scale / dims[0]
    return VoxelGrid(coords, np.asarray(translate), size, {}, (dims[0], dims[2], dims[1]),
                     {"format": "binvox", "path": str(path)})


def _runs(flat_occupied: np.ndarray, total: int) -> bytes:
    """binvox run-length bytes of the sorted linear indices ``flat_occupied`` in ``range(total)``."""
    # Alternating empty/filled segments: boundaries where a run of consecutive indices starts or ends.
    breaks = np.flatnonzero(np.diff(flat_occupied) != 1) + 1
    run_start = flat_occupied[np.r_[0, breaks]] if len(flat_occupied) else np.zeros(0, np.int64)
    run_end = flat_occupied[np.r_[breaks - 1, len(flat_occupied) - 1]] + 1 if len(flat_occupied) else run_start
    edges = np.stack([run_start, run_end], axis=1).reshape(-1)
    bounds = np.r_[0, edges, total]
    lengths = np.diff(bounds)
    values = np.tile(np.array([0, 1], np.uint8), len(run_start) + 1)[: len(lengths)]
    keep = lengths > 0
    values, lengths = values[keep], lengths[keep]
    pieces = -(-lengths // 255)
    piece_values = np.repeat(values, pieces)
    piece_lengths = np.full(int(pieces.sum()), 255, np.int64)
    last = np.cumsum(pieces) - 1
    piece_lengths[last] = lengths - 255 * (pieces - 1)
    out = np.empty(2 * len(piece_values), np.uint8)
    out[0::2], out[1::2] = piece_values, piece_lengths
    return out.tobytes()


def _write_binvox(tmp: Path, grid: VoxelGrid, path: Path) -> None:
    dim = max(max(grid.shape), 1)  # binvox grids are cubes: the longest axis, the others padded
    if dim > MAX_BINVOX_DIM:
        raise FormatError(path, f"the grid spans {dim} voxels; binvox readers take at most {MAX_BINVOX_DIM} per axis")
    x, y, z = grid.coords.T
    flat = np.sort(x * (dim * dim) + z * dim + y)
    header = (f"#binvox 1\ndim {dim} {dim} {dim}\ntranslate {' '.join(repr(float(v)) for v in grid.origin)}\n"
              f"scale {float(grid.size * dim)!r}\ndata\n").encode("ascii")
    tmp.write_bytes(header + _runs(flat, dim**3))


# -- MagicaVoxel .vox -----------------------------------------------------------------------


def _chunks(data: bytes, start: int, stop: int, path: Path):
    """``(id, content, children_start, children_stop)`` of the chunks in ``data[start:stop]``."""
    at = start
    while at < stop:
        if at + 12 > stop:
            raise FormatError(path, f"vox chunk header at byte {at} is cut short (file or parent chunk ends at {stop})")
        ident = data[at : at + 4]
        content, children = struct.unpack_from("<ii", data, at + 4)
        if content < 0 or children < 0 or at + 12 + content + children > stop:
            raise FormatError(path, f"vox chunk {ident!r} at byte {at} declares {content} + {children} bytes, "
                              f"beyond the {stop - at - 12} left")
        yield ident, data[at + 12 : at + 12 + content], at + 12 + content, at + 12 + content + children
        at += 12 + content + children


def read_vox(path: Path) -> VoxelGrid:
    data = path.read_bytes()
    if len(data) < 8 or data[:4] != b"VOX ":
        raise FormatError(path, "not a MagicaVoxel file: expected 'VOX ' and a version")
    mains = list(_chunks(data, 8, len(data), path))
    if not mains or mains[0][0] != b"MAIN":
        raise FormatError(path, "vox file has no MAIN chunk after its header")
    sizes, models, palette = [], [], None
    for ident, content, _first, _stop in _chunks(data, mains[0][2], mains[0][3], path):
        if ident == b"SIZE":
            if len(content) < 12:
                raise FormatError(path, f"vox SIZE chunk has {len(content)} bytes; expected 12")
            sizes.append(struct.unpack_from("<iii", content))
        elif ident == b"XYZI":
            if len(content) < 4:
                raise FormatError(path, "vox XYZI chunk has no voxel count")
            (count,) = struct.unpack_from("<i", content)
            if count < 0 or 4 + 4 * count > len(content):
                raise FormatError(path, f"vox XYZI declares {count:,} voxels ({4 * count:,} bytes) but holds "
                                  f"{len(content) - 4:,} bytes")
            models.append(np.frombuffer(content, np.uint8, count=4 * count, offset=4).reshape(count, 4))
        elif ident == b"RGBA":
            if len(content) < 1024:
                raise FormatError(path, f"vox RGBA chunk has {len(content)} bytes; expected 1024")
            palette = np.frombuffer(content, np.uint8, count=1024).reshape(256, 4)
    if not models or len(sizes) < len(models):
        raise FormatError(path, f"vox file has {len(sizes)} SIZE and {len(models)} XYZI chunks; expected a pair per model")
    if len(models) > 1:
        warnings.warn(f"{path}: {len(models)} models; read the first (pointfield does not place MagicaVoxel's "
                      "scene graph)", stacklevel=3)
    shape, voxels = sizes[0], models[0]
    if min(shape) < 1 or max(shape) > MAX_VOX_AXIS:
        raise FormatError(path, f"vox model size {shape} is outside 1..{MAX_VOX_AXIS} per axis")
    coords = voxels[:, :3].astype(np.int64)
    if len(coords) and (coords >= np.asarray(shape)).any():
        raise FormatError(path, f"vox voxel coordinates reach {coords.max(axis=0).tolist()}, outside the model size {shape}")
    colors = (palette if palette is not None else _default_palette())[(voxels[:, 3].astype(np.int64) - 1) % 256, :3]
    coords, first = np.unique(coords, axis=0, return_index=True)  # a repeated voxel: its first colour
    return VoxelGrid(coords, np.zeros(3), 1.0, {"colors": colors[first].copy()}, tuple(shape),
                     {"format": "vox", "path": str(path), "models": len(models)})


def _default_palette() -> np.ndarray:
    """MagicaVoxel's palette when a file has no RGBA chunk: a 6x6x6 colour cube then greys (a stand-in for its defaults)."""
    levels = np.array([255, 204, 153, 102, 51, 0], np.uint8)
    cube = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), -1).reshape(-1, 3)[::-1]
    grey = np.linspace(238, 17, 40).astype(np.uint8)
    rgb = np.concatenate([cube, np.stack([grey] * 3, 1)])[:256]
    return np.concatenate([rgb, np.full((256, 1), 255, np.uint8)], axis=1)


def _chunk(ident: bytes, content: bytes, children: bytes = b"") -> bytes:
    return ident + struct.pack("<ii", len(content), len(children)) + content + children


def _palette_indices(colors: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Colour index 1..255 per voxel and the 256 x 4 RGBA palette (PIL's median cut past 255 colours)."""
    palette = np.zeros((256, 4), np.uint8)
    palette[:, 3] = 255
    if colors is None:
        palette[0, :3] = 200
        return np.ones(n, np.uint8), palette
    rgb = np.asarray(colors)[:, :3]
    if np.issubdtype(rgb.dtype, np.floating):
        rgb = np.rint(np.clip(rgb, 0, 1) * 255)
    rgb = rgb.astype(np.uint8)
    unique, inverse = np.unique(rgb, axis=0, return_inverse=True)
    if len(unique) > 255:
        from PIL import Image

        image = Image.fromarray(rgb[None]).quantize(255, method=Image.Quantize.MEDIANCUT)
        inverse = np.asarray(image).reshape(-1)
        unique = np.asarray(image.getpalette()[: 255 * 3], np.uint8).reshape(-1, 3)
    palette[: len(unique), :3] = unique
    return (inverse.reshape(-1) + 1).astype(np.uint8), palette


def _write_vox(tmp: Path, grid: VoxelGrid, path: Path) -> None:
    if max(grid.shape) > MAX_VOX_AXIS:
        fits = max(grid.shape) * grid.size / (MAX_VOX_AXIS - 1)
        raise FormatError(path, f"a MagicaVoxel model holds at most {MAX_VOX_AXIS} voxels per axis; this grid is "
                          f"{' x '.join(map(str, grid.shape))}: voxelize with --voxel {fits:.3g} or larger, "
                          "or write .binvox or .npz")
    index, palette = _palette_indices(grid.fields.get("colors"), len(grid))
    voxels = np.concatenate([grid.coords.astype(np.uint8), index[:, None]], axis=1)
    size = _chunk(b"SIZE", struct.pack("<iii", *(max(1, s) for s in grid.shape)))
    xyzi = _chunk(b"XYZI", struct.pack("<i", len(voxels)) + voxels.tobytes())
    rgba = _chunk(b"RGBA", palette.tobytes())
    tmp.write_bytes(b"VOX " + struct.pack("<i", 150) + _chunk(b"MAIN", b"", size + xyzi + rgba))


# -- NPZ ------------------------------------------------------------------------------------


def read_npz(path: Path) -> VoxelGrid:
    try:
        with zipfile.ZipFile(path) as archive:
            infos = {info.filename.removesuffix(".npy"): info for info in archive.infolist()}
            for name, info in infos.items():
                if info.file_size > max(info.compress_size, 1) * NPZ_MAX_EXPANSION:
                    raise FormatError(path, f"member {name!r} claims {info.file_size:,} bytes from "
                                      f"{info.compress_size:,} compressed (more than deflate can expand)")
        missing = {"coords", "origin", "size"} - set(infos)
        if missing:
            raise FormatError(path, f"not a voxel NPZ: no {sorted(missing)} member(s) (expected coords, origin, size)")
        with np.load(path, allow_pickle=False) as archive:
            coords = archive["coords"]
            origin, size = archive["origin"], archive["size"]
            shape = tuple(int(v) for v in archive["shape"]) if "shape" in infos else None
            fields = {name.removeprefix("field/"): archive[name] for name in infos if name.startswith("field/")}
            metadata = json.loads(str(archive["__metadata__"])) if "__metadata__" in infos else {}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as error:
        if isinstance(error, FormatError):
            raise
        raise FormatError(path, f"unreadable voxel NPZ ({error})") from None
    if coords.ndim != 2 or coords.shape[1] != 3 or not np.issubdtype(coords.dtype, np.integer):
        raise FormatError(path, f"'coords' must be (N, 3) integers, got {coords.dtype} {coords.shape}")
    try:
        return VoxelGrid(coords, origin, float(size), fields, shape, {**metadata, "format": "npz", "path": str(path)})
    except (ValueError, TypeError) as error:
        raise FormatError(path, str(error)) from None


def _write_npz(tmp: Path, grid: VoxelGrid, path: Path) -> None:
    members = {"coords": grid.coords, "origin": grid.origin, "size": np.float64(grid.size),
               "shape": np.asarray(grid.shape, np.int64),
               "__metadata__": np.asarray(json.dumps(grid.metadata, default=str))}
    members.update({f"field/{name}": values for name, values in grid.fields.items()})
    with open(tmp, "wb") as file:
        np.savez_compressed(file, **members)
