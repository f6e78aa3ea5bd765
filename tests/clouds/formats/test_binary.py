"""The shared binary machinery: one size check before any allocation, one record reader."""

from __future__ import annotations

import io
import re
import struct
import zipfile

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud
from pointfield.clouds.formats.binary import check_size, read_records, record_dtype

FIVE_POINTS = PointCloud(np.arange(15, dtype=np.float32).reshape(5, 3))


def inflate_ply(data: bytes) -> bytes:
    return data.replace(b"element vertex 5\n", b"element vertex 500\n", 1)


def inflate_pcd(data: bytes) -> bytes:
    return data.replace(b"WIDTH 5\n", b"WIDTH 500\n").replace(b"POINTS 5\n", b"POINTS 500\n")


def inflate_npy(data: bytes) -> bytes:
    # Same length, so the header's padding still lines the data up.
    return data.replace(b"'shape': (5,)", b"'shape': (9,)", 1)


def inflate_npz(data: bytes) -> bytes:
    # The points member's header, re-archived with a matching CRC so that only its size is wrong.
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as archive, zipfile.ZipFile(out, "w") as inflated:
        for info in archive.infolist():
            member = archive.read(info)
            if info.filename == "points.npy":
                member = member.replace(b"'shape': (5, 3)", b"'shape': (9, 3)", 1)
            inflated.writestr(info.filename, member)
    return out.getvalue()


def inflate_las(data: bytes) -> bytes:
    # LAS 1.2: the legacy point count is the uint32 at byte 107.
    return data[:107] + struct.pack("<I", 5000) + data[111:]


# name, encoding, how to make its header declare more points than the file holds
DECLARING_FORMATS = [
    ("cloud.ply", "binary_little_endian", inflate_ply),
    ("cloud.ply", "binary_big_endian", inflate_ply),
    ("cloud.pcd", "binary", inflate_pcd),
    ("cloud.npy", None, inflate_npy),
    ("cloud.npz", "stored", inflate_npz),
    ("cloud.las", None, inflate_las),
]


@pytest.mark.parametrize(
    ("name", "encoding", "inflate"),
    DECLARING_FORMATS,
    ids=[f"{name}-{encoding}" for name, encoding, _ in DECLARING_FORMATS],
)
def test_header_declaring_more_points_than_the_file_holds_is_refused(
    tmp_path, name, encoding, inflate
):
    path = tmp_path / name
    pointfield.write(path, FIVE_POINTS, encoding=encoding)
    original = path.read_bytes()
    path.write_bytes(inflate(original))
    assert path.read_bytes() != original
    with pytest.raises(FormatError, match=re.escape(str(path))) as caught:
        pointfield.read(path)
    assert "declares" in str(caught.value) and "but only" in str(caught.value)


def test_size_check_names_the_declaration_and_both_sizes():
    with pytest.raises(FormatError) as caught:
        check_size("scan.pcd", "header", 10, 16, 12, unit="points")
    assert str(caught.value) == (
        "scan.pcd: header declares 10 points of 16 bytes: it needs 160 bytes but only 12 follow"
    )


def test_size_check_passes_records_that_fit_exactly():
    check_size("scan.pcd", "header", 10, 16, 160)


def test_records_of_either_byte_order_read_as_native_values():
    values = np.array([(1.5, [1, 2, 3]), (-2.0, [4, 5, 6])], [("a", "f4"), ("b", "i4", (3,))])
    for order in "<>":
        dtype = record_dtype([("a", np.dtype("f4")), ("b", np.dtype("i4"), (3,))], order)
        stored = values.astype(dtype).tobytes()
        records = read_records(b"xx" + stored, dtype, 2, offset=2)
        assert records.dtype.isnative and records.dtype["b"].base.isnative
        np.testing.assert_array_equal(records["a"], values["a"])
        np.testing.assert_array_equal(records["b"], values["b"])


def test_record_layout_can_skip_padding_bytes():
    dtype = record_dtype([("x", np.dtype("f4")), ("y", np.dtype("f4"))], "<", [0, 8], 12)
    stored = np.array([1.0, 99.0, 2.0], "<f4").tobytes()
    records = read_records(stored, dtype, 1)
    assert (records["x"][0], records["y"][0]) == (1.0, 2.0)
