"""Mutation fuzzing of the file readers, shared by the test suite and benchmarks/bench_fuzz.py.

Each input is a seed file (a small real file from ../shared/data, or one pointfield wrote) changed
by one seeded mutation. Reading it must give a cloud or a FormatError: anything else is a bug.
"""

from __future__ import annotations

import importlib.util
import re
import signal
import struct
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import pointfield
from pointfield import FormatError, Mesh, PointCloud, Records

HAS_PYE57 = importlib.util.find_spec("pye57") is not None
"""E57 is read and written through the optional pye57 (``pointfield[e57]``): without it, no E57 seeds."""

# Real files small enough to mutate thousands of times, one or more per reader and encoding.
REAL_SEEDS = (
    "pcd/pcl_bunny_ascii.pcd",
    "pcd/pcl_curve_close_binary.pcd",
    "pcd/pcl_logo_binary_compressed.pcd",
    "pcd/pcl_brisk_descriptors_count64.pcd",
    "pcd/pdal_utm17_space_ascii.pcd",
    "ply/pcl_cube_binary_le.ply",
    "ply/plyfile_tet_ascii_face_colors.ply",
    "ply/pdal_sized_dims_ascii.ply",
    "ply/trimesh_points_bin.ply",
    "ply/trimesh_fuze_binary_le_colors_texcoord.ply",
    "las/simple.las",
    "las/simple.laz",
    "xyz_pts/pdal_autzen.pts",
    "xyz_pts/trimesh_points_agisoft.xyz",
    "modelnet/ModelNet10/chair/train/chair_0002.off",
    "e57/pdal_A4.e57",
)

HANG_LIMIT_S = 20  # a reader still busy after this long is hung, not slow


@dataclass(frozen=True)
class Seed:
    name: str
    data: bytes
    suffix: str


def generated_seeds(workdir: Path) -> list[Seed]:
    """One small file per writable format and encoding, written by pointfield itself, and the
    files it cannot write: a two-scan Leica PTX with a transform, a LASzip 1.2r0 LAZ."""
    rng = np.random.default_rng(7)
    n = 40
    cloud = PointCloud(
        rng.normal(size=(n, 3)).astype(np.float32),
        {
            "colors": rng.integers(0, 256, (n, 3), dtype=np.uint8),
            "normals": rng.normal(size=(n, 3)).astype(np.float32),
            "intensity": rng.random(n).astype(np.float32),
        },
    )
    mesh = Mesh(
        np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32),
        faces=np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], np.int32),
    )
    seeds = []
    for fmt in pointfield.clouds.formats.formats():
        if fmt.write is None:
            continue
        if fmt.name == "e57" and not HAS_PYE57:
            continue  # nothing writes E57 without pye57
        for encoding in fmt.encodings or (None,):
            for suffix in fmt.suffixes[:1]:
                for kind, item in (("cloud", cloud), ("mesh", mesh)):
                    if kind == "mesh" and not fmt.holds_faces:
                        continue
                    if kind == "cloud" and fmt.needs_faces:
                        continue  # it refuses a cloud without faces
                    path = workdir / f"{fmt.name}-{encoding}-{kind}{suffix}"
                    with warnings.catch_warnings(action="ignore"):
                        pointfield.write(path, item, format=fmt.name, encoding=encoding)
                    seeds.append(Seed(path.name, path.read_bytes(), suffix))
    seeds.append(Seed("ptx-two-scans.ptx", two_scan_ptx().encode(), ".ptx"))
    laz = next(seed.data for seed in seeds if seed.name == "las-laz-cloud.las")
    seeds.append(Seed("laszip-1.2r0.laz", legacy_laszip(laz), ".laz"))
    return seeds


# ---------------------------------------------------------------------------------------------
# Seeds pointfield does not write itself


def two_scan_ptx() -> str:
    """A Leica PTX file as scanners write it: two organised scans (3 x 2 and 2 x 2 cells, one
    without a return), colours, and a second scan rotated a quarter turn about z and moved."""
    first = [
        "0.5 1.25 -0.75 0.25 10 20 30", "1.5 1.0 -0.5 0.5 40 50 60", "0 0 0 0.5 0 0 0",
        "2.5 0.75 0.25 0.125 70 80 90", "3.5 0.5 0.5 1 100 110 120", "4.5 0.25 1.5 0.75 1 2 3",
    ]
    second = [
        "1 2 3 0.1 255 0 0", "4 5 6 0.2 0 255 0", "7 8 9 0.3 0 0 255", "-1 -2 -3 0.4 9 9 9",
    ]
    identity = ["1 0 0", "0 1 0", "0 0 1", "1 0 0 0", "0 1 0 0", "0 0 1 0", "0 0 0 1"]
    turned = ["0 1 0", "-1 0 0", "0 0 1", "0 1 0 0", "-1 0 0 0", "0 0 1 0", "10 20 30 1"]
    lines = ["3", "2", "0 0 0", *identity, *first, "2", "2", "10 20 30", *turned, *second]
    return "\n".join(lines) + "\n"


def legacy_laszip(laz: bytes) -> bytes:
    """A single-chunk LAZ file as the LASzip 1.2r0 compressor wrote it: one pointwise stream
    whose LASzip record declares variable-size chunks, and no chunk table.

    A single chunk of the pointwise-chunked compressor holds the same stream, so the chunk
    table offset before it and the table after it are dropped and the record rewritten
    (compressor 1, version 1.2r0, chunk size 2**32 - 1). LAS 1.0 to 1.3 files without EVLRs.
    """
    data = bytearray(laz)
    header_size, offset_to_points, vlr_count = struct.unpack_from("<HII", data, 94)
    position = header_size
    for _ in range(vlr_count):
        user_id = bytes(data[position + 2 : position + 18]).rstrip(b"\0")
        record_id, length = struct.unpack_from("<HH", data, position + 18)
        if (user_id, record_id) == (b"laszip encoded", 22204):
            record = position + 54
            (compressor,) = struct.unpack_from("<H", data, record)
            assert compressor == 2, f"expected a pointwise-chunked LAZ, got compressor {compressor}"
            struct.pack_into("<HxxBBH", data, record, 1, 1, 2, 0)
            struct.pack_into("<I", data, record + 12, 2**32 - 1)
        position += 54 + length
    (table,) = struct.unpack_from("<q", data, offset_to_points)
    (chunks,) = struct.unpack_from("<I", data, table + 4)
    assert chunks == 1, f"expected one LAZ chunk, got {chunks}"
    return bytes(data[:offset_to_points] + data[offset_to_points + 8 : table])


def real_seeds(shared_data: Path) -> list[Seed]:
    """The real files of REAL_SEEDS, but E57 where pye57 is missing (nothing reads one then)."""
    return [
        Seed(rel, (shared_data / rel).read_bytes(), Path(rel).suffix)
        for rel in REAL_SEEDS if HAS_PYE57 or not rel.endswith(".e57")
    ]


def mutations(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One random mutation of ``data``: its description and the mutated bytes."""
    n = len(data)
    kind = rng.integers(8)
    if kind == 0 or n == 0:
        cut = int(rng.integers(0, n + 1))
        return f"truncate at {cut}", data[:cut]
    if kind == 1:
        out = bytearray(data)
        for _ in range(int(rng.integers(1, 9))):
            i = int(rng.integers(n))
            out[i] ^= 1 << int(rng.integers(8))
        return "flip bits", bytes(out)
    if kind == 2:
        i = int(rng.integers(n))
        j = min(n, i + int(rng.integers(1, 64)))
        return f"delete {i}:{j}", data[:i] + data[j:]
    if kind == 3:
        i = int(rng.integers(n + 1))
        junk = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
        return f"insert {len(junk)} at {i}", data[:i] + junk + data[i:]
    if kind == 4:
        return _mutate_header_number(data, rng)
    if kind == 5:
        i = int(rng.integers(n))
        out = bytearray(data)
        out[i : i + 8] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
        return f"overwrite 8 at {i}", bytes(out[:n])
    if kind == 6:
        keep = int(rng.integers(1, min(n, 16) + 1))
        junk = rng.integers(0, 256, int(rng.integers(0, 2048)), dtype=np.uint8).tobytes()
        return f"keep {keep} magic bytes then random", data[:keep] + junk
    i = int(rng.integers(n))
    return f"duplicate from {i}", data[:i] + data[i : i + 512] + data[i:]


_NUMBER = re.compile(rb"-?\d+")
_HOSTILE_NUMBERS = (b"0", b"-1", b"-2147483648", b"4294967295", b"1000000000000", b"99999999999999999999")


def _mutate_header_number(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    matches = list(_NUMBER.finditer(data[:2048]))
    if not matches:
        return "no header number", data
    m = matches[int(rng.integers(len(matches)))]
    new = _HOSTILE_NUMBERS[int(rng.integers(len(_HOSTILE_NUMBERS)))]
    return f"number at {m.start()} -> {new.decode()}", data[: m.start()] + new + data[m.end() :]


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang


def run_case(path: Path) -> tuple[str, float]:
    """Read ``path``; return the outcome ("cloud" or "FormatError") and the seconds it took.

    Any other exception propagates, so the caller sees the bug with its traceback.
    """
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_LIMIT_S)
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(action="ignore"):
            result = pointfield.read(path)
        assert isinstance(result, (PointCloud, Records)), type(result)
        outcome = "cloud"
    except FormatError as error:
        assert str(path) in str(error), f"error does not name the file: {error}"
        outcome = "FormatError"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return outcome, time.perf_counter() - start


def cases(seeds: list[Seed], per_seed: int, seed: int) -> Iterator[tuple[Seed, str, bytes]]:
    rng = np.random.default_rng(seed)
    for s in seeds:
        for _ in range(per_seed):
            description, data = mutations(s.data, rng)
            yield s, description, data

