"""read_chunks: windows of a file that, put together, are exactly what pointfield.read returns."""

from __future__ import annotations

import struct
import warnings

import laspy
import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import same_fields
from pointfield.streaming import StreamingFallback, open_source
from pointfield.streaming.chunks import concatenate

CHUNK = 3_000  # points per chunk: small, so that every file is many chunks


def assert_same_cloud(a, b):
    assert a.points.dtype == b.points.dtype
    assert np.array_equal(a.points, b.points, equal_nan=True)
    assert same_fields(a.fields, b.fields)


@pytest.mark.parametrize("kind", ["laz", "las", "ply", "pcd", "npy", "bin"])
def test_chunks_put_together_are_the_whole_file(data, kind):
    chunks = list(pointfield.read_chunks(data[kind], points=CHUNK))
    whole = pointfield.read(data[kind])
    assert len(chunks) == -(-len(whole) // CHUNK)
    assert all(len(c) <= CHUNK for c in chunks)
    assert_same_cloud(concatenate(chunks), whole)
    assert chunks[-1].metadata == whole.metadata


def test_a_window_anywhere_is_the_same_points_as_the_whole_file(data):
    source = open_source(data["laz"])
    whole = pointfield.read(data["laz"])
    window = source.read(12_345, 23_456)
    assert_same_cloud(window, whole.select(slice(12_345, 23_456)))


def test_formats_that_cannot_stream_say_so_and_are_read_whole(tmp_path, data):
    ascii_file = tmp_path / "strip.xyz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pointfield.write(ascii_file, pointfield.read(data["ply"]))
    with pytest.warns(StreamingFallback, match="read whole"):
        chunks = list(pointfield.read_chunks(ascii_file, points=CHUNK))
    assert_same_cloud(concatenate(chunks), pointfield.read(ascii_file))


def test_real_files_stream_as_they_read(shared_data):
    for name in ("las/autzen_trim.laz", "las/extrabytes.las", "ply/pcu_duplicated_pcloud_double_normals.ply",
                 "pcd/pcl_office1_keypoints_binary.pcd", "kitti/mmdet3d_demo/000008.bin"):
        path = shared_data / name
        assert open_source(path).streams, name
        assert_same_cloud(concatenate(list(pointfield.read_chunks(path, points=1000))), pointfield.read(path))


def test_a_copc_query_streams_the_octree_nodes_it_needs(shared_data):
    path = shared_data / "las" / "simple.copc.laz"
    with laspy.CopcReader.open(str(path)) as reader:
        low, high = reader.header.mins, reader.header.maxs
        middle = (low + high) / 2
        expected = reader.query(bounds=laspy.Bounds(low[:2], middle[:2]))
        root = reader.query(level=0)
    box = (*low[:2], *middle[:2])
    chunks = list(pointfield.read_chunks(path, points=100, bounds=box))
    queried = concatenate(chunks)
    assert len(queried) == len(expected)
    assert np.array_equal(np.sort(queried.points[:, 0]), np.sort(np.asarray(expected.x)))
    assert len(concatenate(list(pointfield.read_chunks(path, level=0)))) == len(root)


def test_a_ply_cut_mid_vertex_is_refused_naming_the_file_and_the_vertex(tmp_path, data):
    data_bytes = data["ply"].read_bytes()
    header_end = data_bytes.index(b"end_header\n") + len(b"end_header\n")
    record = (len(data_bytes) - header_end) // len(pointfield.read(data["ply"]))
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data_bytes[: header_end + 1234 * record + 5])
    with pytest.raises(pointfield.FormatError, match=r"cut\.ply.*vertex 1,234 of 40,000 is cut short"):
        open_source(cut)


def test_a_laz_cut_at_60_percent_is_refused_naming_the_file_and_the_point(tmp_path, data):
    whole = data["laz"].read_bytes()
    cut = tmp_path / "cut.laz"
    cut.write_bytes(whole[: int(len(whole) * 0.6)])
    with pytest.raises(pointfield.FormatError, match=r"cut\.laz: LAZ data is cut short.*breaks around point [\d,]+ of 40,000"):
        list(pointfield.read_chunks(cut, points=CHUNK))


def test_a_corrupt_laz_chunk_names_the_points_it_broke_in(tmp_path, data):
    broken = bytearray(data["laz"].read_bytes())
    offset = struct.unpack_from("<I", broken, 96)[0]
    middle = offset + (len(broken) - offset) // 2
    broken[middle : middle + 400] = bytes(400)
    path = tmp_path / "corrupt.laz"
    path.write_bytes(bytes(broken))
    with pytest.raises(pointfield.FormatError, match=r"corrupt\.laz: LAZ data is corrupt in points [\d,]+ to [\d,]+"):
        for _ in pointfield.read_chunks(path, points=CHUNK):
            pass
