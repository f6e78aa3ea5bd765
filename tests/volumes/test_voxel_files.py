""".binvox, MagicaVoxel .vox and NPZ: round trips, their limits, and hostile or truncated files."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from pointfield.errors import FormatError
from pointfield.volumes import VoxelGrid, read_voxels, write_voxels
from pointfield.volumes.files import MAX_VOX_AXIS


def random_grid(seed: int = 0, shape=(40, 30, 20), count: int = 3000, origin=(-1.5, 2.0, 0.25), size=0.125):
    rng = np.random.default_rng(seed)
    flat = rng.choice(np.prod(shape), count, replace=False)
    coords = np.stack(np.unravel_index(flat, shape), axis=1)
    colors = rng.integers(0, 256, (count, 3)).astype(np.uint8)
    return VoxelGrid(coords, np.array(origin), size, {"colors": colors, "counts": rng.integers(1, 9, count)}, shape)


def test_binvox_round_trip_keeps_voxels_origin_and_size(tmp_path):
    grid = random_grid()
    write_voxels(tmp_path / "g.binvox", grid)
    back = read_voxels(tmp_path / "g.binvox")
    assert np.array_equal(back.coords, grid.coords)
    assert np.allclose(back.centres(), grid.centres())
    assert back.size == grid.size and back.shape == (40, 40, 40)  # binvox grids are cubes


def test_binvox_reads_the_layout_y_fastest_then_z_then_x(tmp_path):
    # dim 2: voxel index x*4 + z*2 + y; runs: 5 empty then 1 full -> index 5 = x 1, z 0, y 1.
    header = b"#binvox 1\ndim 2 2 2\ntranslate 0 0 0\nscale 2\ndata\n"
    (tmp_path / "one.binvox").write_bytes(header + bytes([0, 5, 1, 1, 0, 2]))
    grid = read_voxels(tmp_path / "one.binvox")
    assert grid.coords.tolist() == [[1, 1, 0]]
    assert grid.centres().tolist() == [[1.5, 1.5, 0.5]]


def test_runs_longer_than_255_voxels_are_split(tmp_path):
    grid = VoxelGrid(np.argwhere(np.ones((10, 10, 10), bool)), size=0.1)
    write_voxels(tmp_path / "full.binvox", grid)
    data = (tmp_path / "full.binvox").read_bytes().split(b"data\n", 1)[1]
    assert list(data) == [1, 255, 1, 255, 1, 255, 1, 235]
    assert len(read_voxels(tmp_path / "full.binvox")) == 1000


def test_vox_round_trip_keeps_coordinates_and_colours(tmp_path):
    grid = random_grid(count=200)
    grid.fields["colors"] = grid.fields["colors"] // 64 * 64  # 64 colours: the palette holds them exactly
    write_voxels(tmp_path / "g.vox", grid)
    back = read_voxels(tmp_path / "g.vox")
    assert np.array_equal(back.coords, grid.coords)
    assert np.array_equal(back.fields["colors"], grid.fields["colors"])
    assert back.size == 1.0 and np.all(back.origin == 0)  # .vox stores neither


def test_vox_with_more_than_255_colours_gets_a_median_cut_palette(tmp_path):
    grid = random_grid(count=3000)
    write_voxels(tmp_path / "g.vox", grid)
    back = read_voxels(tmp_path / "g.vox")
    assert len(np.unique(back.fields["colors"], axis=0)) <= 255
    error = np.abs(back.fields["colors"].astype(int) - grid.fields["colors"]).mean()
    assert error < 20  # of 255: the nearest of 255 colours, not an arbitrary one


def test_vox_refuses_a_grid_beyond_256_per_axis_and_writes_nothing(tmp_path):
    grid = VoxelGrid(np.array([[0, 0, 0], [MAX_VOX_AXIS, 0, 0]]), size=0.5)
    with pytest.raises(FormatError, match=r"at most 256 voxels per axis; this grid is 257 x 1 x 1: voxelize with --voxel"):
        write_voxels(tmp_path / "big.vox", grid)
    assert list(tmp_path.iterdir()) == []


def test_npz_round_trip_keeps_every_field(tmp_path):
    grid = random_grid()
    grid.metadata["source"] = "scan.ply"
    write_voxels(tmp_path / "g.npz", grid)
    back = read_voxels(tmp_path / "g.npz")
    assert np.array_equal(back.coords, grid.coords) and back.shape == grid.shape
    assert np.array_equal(back.origin, grid.origin) and back.size == grid.size
    for name in grid.fields:
        assert np.array_equal(back.fields[name], grid.fields[name])
    assert back.metadata["source"] == "scan.ply"


def test_truncated_binvox_is_refused_naming_the_file(tmp_path):
    write_voxels(tmp_path / "g.binvox", random_grid())
    data = (tmp_path / "g.binvox").read_bytes()
    (tmp_path / "cut.binvox").write_bytes(data[:-40])
    with pytest.raises(FormatError, match=r"cut\.binvox: binvox runs cover .* voxels but .dim 40 40 40. declares 64,000"):
        read_voxels(tmp_path / "cut.binvox")


def test_binvox_with_a_huge_declared_size_is_refused(tmp_path):
    (tmp_path / "huge.binvox").write_bytes(b"#binvox 1\ndim 99999999 2 2\ntranslate 0 0 0\nscale 1\ndata\n\x00\xff")
    with pytest.raises(FormatError, match=r"huge\.binvox: binvox 'dim' must be three sizes in 1\.\.16384"):
        read_voxels(tmp_path / "huge.binvox")


def test_vox_chunk_claiming_more_bytes_than_the_file_is_refused(tmp_path):
    write_voxels(tmp_path / "g.vox", random_grid(count=50))
    data = bytearray((tmp_path / "g.vox").read_bytes())
    xyzi = data.index(b"XYZI")
    data[xyzi + 12 : xyzi + 16] = struct.pack("<i", 10**8)  # the voxel count inside XYZI
    (tmp_path / "lying.vox").write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"lying\.vox: vox XYZI declares 100,000,000 voxels"):
        read_voxels(tmp_path / "lying.vox")
    (tmp_path / "short.vox").write_bytes(bytes(data[: xyzi + 20]))
    with pytest.raises(FormatError, match=r"short\.vox: vox chunk"):
        read_voxels(tmp_path / "short.vox")


def test_npz_that_is_not_a_voxel_grid_is_refused(tmp_path):
    np.savez(tmp_path / "cloud.npz", points=np.zeros((3, 3)))
    with pytest.raises(FormatError, match=r"cloud\.npz: not a voxel NPZ"):
        read_voxels(tmp_path / "cloud.npz")


def test_unknown_bytes_are_refused(tmp_path):
    (tmp_path / "x.binvox").write_bytes(b"hello world")
    with pytest.raises(FormatError, match=r"x\.binvox: not a voxel file"):
        read_voxels(tmp_path / "x.binvox")
