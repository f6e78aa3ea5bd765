"""Warnings are for the user: they name the user's file (never the temporary file a write goes
through), point at the user's own line from Python, and say nothing about details of files
pointfield chose to write itself."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud


def organised_cloud() -> PointCloud:
    return PointCloud(np.arange(12, dtype=np.float32).reshape(4, 3), shape=(2, 2))


def test_convert_warns_about_the_output_not_its_temporary_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pointfield.write("scan.pcd", organised_cloud())  # PCD keeps the 2 x 2 layout; PLY cannot
    assert main(["cloud", "convert", "scan.pcd", "scan.ply"]) == 0
    err = capsys.readouterr().err
    assert "pointfield: warning: scan.ply: PLY has no organised layout" in err
    assert ".tmp" not in err and ".scan." not in err


def test_write_warns_the_python_way_naming_the_file_and_the_callers_line(tmp_path):
    cloud = PointCloud(np.zeros((3, 3)), {"ids": np.arange(3, dtype=np.int64)})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pointfield.write(tmp_path / "ids.ply", cloud)
    (warning,) = caught
    assert issubclass(warning.category, UserWarning)
    assert str(warning.message).startswith(f"{tmp_path / 'ids.ply'}: PLY has no 64-bit integers")
    assert ".tmp" not in str(warning.message)
    assert warning.filename == __file__  # this test's line, not a line inside pointfield


def test_a_scene_written_with_colmaps_points_says_nothing_about_their_ids(shared_data, tmp_path, capsys):
    # scene from-images and scene convert write COLMAP's points (64-bit point_id) as a PLY of their own.
    source = shared_data / "colmap" / "tiny_phone_scene"
    assert main(["scene", "convert", str(source), str(tmp_path / "phone"), "--from", "colmap",
                 "--format", "nerfstudio"]) == 0
    err = capsys.readouterr().err
    assert "64-bit" not in err and "point_id" not in err
    points = pointfield.read(next((tmp_path / "phone").glob("*.ply")))
    assert len(points) == 256 and points.fields["point_id"].dtype == np.int32


def test_unregistered_photos_are_told_with_the_scene_and_its_report(tmp_path):
    from pointfield.scenes.sfm.pipeline import PosingOptions, _check_registration

    work = SimpleNamespace(root=tmp_path / "my_scene.partial", state={"data": {}})
    with pytest.warns(UserWarning) as caught:
        _check_registration(5, 6, PosingOptions(), work)
    message = str(caught[0].message)
    assert message.startswith(f"{tmp_path / 'my_scene'}: 1 of 6 photos could not be registered")
    assert str(tmp_path / "my_scene" / "report.json") in message
