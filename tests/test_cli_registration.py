"""`pointfield cloud register`: JSON on stdout, the aligned cloud with every field, bad input as one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scan_pairs import errors, pair

import pointfield
from pointfield.cli import main
from pointfield.registration import Scan


@pytest.fixture
def scans(tmp_path):
    source, target, truth = pair(angle=8.0)
    normals = Scan.from_cloud(source).with_normals().normals.astype(np.float32)
    source = pointfield.PointCloud(source.points, {**source.fields, "normals": normals,
                                                   "label": np.arange(len(source), dtype=np.int32)})
    pointfield.write(tmp_path / "source.ply", source)
    pointfield.write(tmp_path / "target.pcd", target)
    return tmp_path / "source.ply", tmp_path / "target.pcd", truth


def _one_line_error(capsys, argv, *fragments):
    assert main([str(a) for a in argv]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pointfield: error:"), captured.err
    assert captured.out == ""
    for fragment in fragments:
        assert str(fragment) in lines[0], lines[0]


def test_json_prints_the_motion_fitness_rmse_and_method(capsys, scans):
    source, target, truth = scans
    assert main(["cloud", "register", str(source), str(target), "--method", "gicp", "--voxel", "0.02", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert {"transformation", "fitness", "rmse", "method"} <= printed.keys()
    assert errors(np.array(printed["transformation"]), truth)[0] < 0.5
    assert printed["method"] == "generalized ICP (small_gicp)" and 0.3 < printed["fitness"] < 0.8


def test_out_writes_the_aligned_source_with_every_field_and_turned_normals(capsys, scans, tmp_path):
    source, target, _ = scans
    out = tmp_path / "aligned.ply"
    init = tmp_path / "init.json"
    init.write_text(json.dumps({"transformation": np.eye(4).tolist()}))
    assert main(["cloud", "register", str(source), str(target), "--init", str(init), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    before, after = pointfield.read(source), pointfield.read(out)
    assert after.fields.keys() == before.fields.keys()
    assert np.array_equal(after.fields["label"], before.fields["label"])
    assert np.array_equal(after.fields["colors"], before.fields["colors"])
    rotation, _, _, _ = np.linalg.lstsq(before.points - before.points.mean(0), after.points - after.points.mean(0),
                                        rcond=None)
    assert np.allclose(after.fields["normals"], before.fields["normals"] @ rotation, atol=1e-4)


def test_a_pair_that_does_not_overlap_gets_a_warning_line(capsys, tmp_path):
    source, target, _ = pair(angle=0.0, translation=(0, 0, 0), overlap_split=0.4)
    pointfield.write(tmp_path / "a.ply", source)
    pointfield.write(tmp_path / "b.ply", target)
    assert main(["cloud", "register", str(tmp_path / "a.ply"), str(tmp_path / "b.ply"), "--method", "icp"]) == 0
    assert ("pointfield: warning: fitness 0.0" in capsys.readouterr().err)


@pytest.mark.parametrize("points, fragment", [
    (np.zeros((0, 3), np.float32), "no points"),
    (np.full((20, 3), np.nan, np.float32), "0 finite points of 20"),
    (np.ones((1, 3), np.float32), "1 finite point of 1"),
])
def test_clouds_that_cannot_be_registered_are_one_line(capsys, scans, tmp_path, points, fragment):
    _, target, _ = scans
    bad = tmp_path / "bad.pcd"
    pointfield.write(bad, pointfield.PointCloud(points))
    _one_line_error(capsys, ["cloud", "register", bad, target], bad, fragment)


@pytest.mark.parametrize("text, fragment", [
    ("[[1, 0, 0], [0, 1, 0", "not JSON"),
    ("[[1, 0, 0], [0, 1, 0], [0, 0, 1]]", "expected a 4 x 4 matrix, got shape (3, 3)"),
    (json.dumps(np.diag([2.0, 2.0, 2.0, 1.0]).tolist()), "not a rigid transformation"),
    (json.dumps(np.diag([1.0, 1.0, -1.0, 1.0]).tolist()), "mirror"),
    ('{"rotation": [1, 0, 0]}', "'transformation'"),
    ('[["a", "b"]]', "not a 4 x 4 matrix of numbers"),
])
def test_bad_init_files_are_one_line(capsys, scans, tmp_path, text, fragment):
    source, target, _ = scans
    init = tmp_path / "T.json"
    init.write_text(text)
    _one_line_error(capsys, ["cloud", "register", source, target, "--init", init], init, fragment)


def test_colored_without_colours_is_one_line(capsys, scans, tmp_path):
    source, _, _ = scans
    bare = tmp_path / "bare.ply"
    pointfield.write(bare, pointfield.PointCloud(pointfield.read(source).points))
    _one_line_error(capsys, ["cloud", "register", source, bare, "--method", "colored", "--init", _identity(tmp_path)],
                    "colored needs colours", "target has none")


def _identity(folder):
    path = folder / "identity.json"
    path.write_text(json.dumps(np.eye(4).tolist()))
    return path
