"""An OctoMap .bt drawn by `cloud render` and shown by `pointfield view`: its occupied cells, as a voxel grid is."""

from __future__ import annotations

import numpy as np
from PIL import Image

from pointfield.cli import main
from pointfield.viewer.clouds import read_prepared
from pointfield.viewer.sources import kind_of
from pointfield.volumes import read_voxels, write_voxels
from pointfield.volumes.occupancy import OccupancyMap, write_octomap


def corridor(tmp_path):
    """A .bt whose ray from the origin crosses 9 free cells of 0.25 and ends in an occupied one, plus a wall of 6."""
    occupancy = OccupancyMap(0.25)
    wall = np.array([[2.6, y, z] for y in (0.1, 0.35, 0.6) for z in (0.1, 0.35)])
    occupancy.insert_scan(np.concatenate([[[2.6, 0.1, 0.1]], wall]), np.array([0.1, 0.1, 0.1]))
    bt = tmp_path / "corridor.bt"
    write_octomap(bt, occupancy)
    return bt, occupancy


def test_cloud_render_draws_a_bt_as_the_voxel_grid_of_its_occupied_cells(tmp_path, capsys):
    bt, occupancy = corridor(tmp_path)
    npz = tmp_path / "occupied.npz"
    write_voxels(npz, occupancy.to_grid("occupied"))
    images = []
    for source in (bt, npz):
        png = tmp_path / f"{source.suffix[1:]}.png"
        assert main(["cloud", "render", str(source), "--out", str(png), "--width", "64", "--height", "48"]) == 0
        images.append(np.asarray(Image.open(png)))
    assert "6 voxel centres" in capsys.readouterr().out  # the wall; the free cells before it are not drawn
    assert (images[0] != 255).any(axis=2).sum() > 50
    assert np.array_equal(images[0], images[1])


def test_view_loads_a_bt_as_its_occupied_cell_centres(tmp_path):
    bt, occupancy = corridor(tmp_path)
    assert kind_of(bt) == "cloud"
    prepared = read_prepared(bt, 1000)
    assert not isinstance(prepared, str), prepared
    expected = occupancy.to_grid("occupied").centres()
    assert len(expected) == 6 and len(occupancy.keys) > 6  # free cells are known but not shown
    assert np.allclose(np.sort(prepared.points, axis=0), np.sort(expected, axis=0))
    assert read_voxels(bt).metadata["occupancy"] == "occupied"
