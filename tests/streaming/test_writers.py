"""Chunk writers: the bytes pointfield.write writes, and a file that appears whole or not at all."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.streaming import StreamingFallback, open_writer

CHUNK = 3_000


def test_a_copc_output_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(pointfield.FormatError, match="cannot write COPC"):
        open_writer(tmp_path / "tiles.copc.laz", bounds=(np.zeros(3), np.ones(3)))
    assert list(tmp_path.iterdir()) == []


def write_both(path_whole, path_chunked, source, encoding=None, bounds=None):
    cloud = pointfield.read(source)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pointfield.write(path_whole, cloud, encoding=encoding)
        with open_writer(path_chunked, encoding, bounds=bounds) as writer:
            for chunk in pointfield.read_chunks(source, points=CHUNK):
                writer.write(chunk)
    return cloud


@pytest.mark.parametrize(
    ("suffix", "encoding"),
    [(".laz", None), (".las", None), (".ply", None), (".ply", "ascii"), (".ply", "binary_big_endian"),
     (".pcd", None), (".pcd", "ascii"), (".npy", None), (".bin", None)],
)
def test_chunked_writing_gives_the_bytes_of_writing_whole(tmp_path, data, suffix, encoding):
    whole, chunked = tmp_path / f"whole{suffix}", tmp_path / f"chunked{suffix}"
    write_both(whole, chunked, data["laz"], encoding)
    assert chunked.read_bytes() == whole.read_bytes()


@pytest.mark.parametrize("bounds", [False, True])
def test_las_renames_fields_it_cannot_name_as_writing_whole_does(tmp_path, bounds):
    rng = np.random.default_rng(0)
    cloud = PointCloud(rng.random((5_000, 3)) * 100, {"GpsTime": rng.random(5_000) * 1e5,
                                                      "las:pointSourceId": np.arange(5_000, dtype=np.uint16),
                                                      "e57:rowIndex": np.arange(5_000, dtype=np.int32)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pointfield.write(tmp_path / "whole.las", cloud)
        with open_writer(tmp_path / "chunked.las", bounds=cloud.bounds() if bounds else None) as writer:
            for start in range(0, len(cloud), 1_200):
                writer.write(cloud.select(slice(start, start + 1_200)))
    assert (tmp_path / "chunked.las").read_bytes() == (tmp_path / "whole.las").read_bytes()


def test_las_bounds_given_up_front_give_the_same_file_as_bounds_found_at_the_end(tmp_path, data):
    cloud = pointfield.read(data["ply"])
    low, high = cloud.bounds()
    write_both(tmp_path / "whole.laz", tmp_path / "waited.laz", data["ply"])
    write_both(tmp_path / "whole.laz", tmp_path / "told.laz", data["ply"], bounds=(low, high))
    assert (tmp_path / "waited.laz").read_bytes() == (tmp_path / "told.laz").read_bytes() == (tmp_path / "whole.laz").read_bytes()


@pytest.mark.parametrize("suffix", [".laz", ".ply", ".pcd"])
def test_a_failure_mid_write_leaves_no_file_and_no_temporaries(tmp_path, data, suffix):
    out = tmp_path / f"out{suffix}"
    with pytest.raises(KeyboardInterrupt), open_writer(out) as writer:
        for number, chunk in enumerate(pointfield.read_chunks(data["laz"], points=CHUNK)):
            if number == 3:
                raise KeyboardInterrupt  # a killed job
            writer.write(chunk)
    assert list(tmp_path.iterdir()) == []


def test_a_failed_rewrite_leaves_the_old_file_as_it_was(tmp_path, data):
    out = tmp_path / "out.ply"
    out.write_bytes(b"the old file")
    with pytest.raises(RuntimeError), open_writer(out) as writer:
        writer.write(next(pointfield.read_chunks(data["laz"], points=CHUNK)))
        raise RuntimeError("disk full")
    assert out.read_bytes() == b"the old file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply"]


def test_formats_that_cannot_be_written_in_chunks_say_so(tmp_path, data):
    with pytest.warns(StreamingFallback, match="written whole"):
        writer = open_writer(tmp_path / "out.pcd", "binary_compressed")
    whole = tmp_path / "whole.pcd"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with writer:
            for chunk in pointfield.read_chunks(data["laz"], points=CHUNK):
                writer.write(chunk)
        pointfield.write(whole, pointfield.read(data["laz"]), encoding="binary_compressed")
    assert (tmp_path / "out.pcd").read_bytes() == whole.read_bytes()


def test_a_chunk_with_other_fields_is_refused(tmp_path, data):
    chunks = pointfield.read_chunks(data["laz"], points=CHUNK)
    first, second = next(chunks), next(chunks)
    del second.fields["intensity"]
    with pytest.raises(pointfield.FormatError, match="fields"), open_writer(tmp_path / "out.ply") as writer:
        writer.write(first)
        writer.write(second)
    assert not (tmp_path / "out.ply").exists()
