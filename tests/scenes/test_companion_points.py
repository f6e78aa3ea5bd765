"""A folder holding both a transforms.json and the COLMAP model it came from: the scene read from
the transforms file carries the model's sparse points across, into its own world frame, so that
``scene cameras`` draws them (the README promises "camera frustums and sparse points")."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from pointfield.cli import main
from pointfield.scenes import read_scene


@pytest.fixture()
def phone_scene(shared_data):
    return shared_data / "colmap" / "tiny_phone_scene"


def test_the_transforms_scene_gets_the_models_points_where_its_cameras_see_them(phone_scene):
    scene = read_scene(phone_scene)
    model = read_scene(phone_scene, format="colmap")
    assert scene.metadata["format"] == "nerfstudio"
    assert scene.points is not None and len(scene.points) == len(model.points) == 256
    assert scene.metadata["points_from"].endswith("sparse/0")
    assert np.array_equal(scene.points.fields["colors"], model.points.fields["colors"])
    # Each point lands on the same pixel of each photo in both descriptions (matched by file name).
    order = [[f.name.split("/")[-1] for f in model.frames].index(f.name.split("/")[-1]) for f in scene.frames]
    ours, _ = scene.cameras.project(torch.from_numpy(scene.points.points.astype(np.float64)))
    theirs, _ = model.cameras[order].project(torch.from_numpy(model.points.points.astype(np.float64)))
    seen = torch.isfinite(ours).all(-1) & torch.isfinite(theirs).all(-1)
    assert seen.float().mean() > 0.9
    assert (ours - theirs)[seen].norm(dim=-1).max() < 1.0  # pixels


def test_scene_cameras_draws_the_points(phone_scene, tmp_path, capsys, monkeypatch):
    import pointfield.scenes.cameras_plot as tools

    drawn = {}
    draw = tools.draw_cameras

    def spy(scene, out, **options):
        drawn["points"] = None if scene.points is None else len(scene.points)
        return draw(scene, out, **options)

    monkeypatch.setattr(tools, "draw_cameras", spy)
    assert main(["scene", "cameras", str(phone_scene), "--out", str(tmp_path / "cams.png")]) == 0
    assert drawn["points"] == 256 and (tmp_path / "cams.png").stat().st_size > 0


def test_a_model_of_other_poses_is_not_carried_across(phone_scene, tmp_path):
    copy = tmp_path / "phone"
    shutil.copytree(phone_scene, copy)
    document = json.loads((copy / "transforms.json").read_text())
    document["frames"][0]["transform_matrix"][0][3] += 1.0  # one camera posed elsewhere: not this model's
    (copy / "transforms.json").write_text(json.dumps(document))
    scene = read_scene(copy)
    assert scene.points is None and "points_from" not in scene.metadata
