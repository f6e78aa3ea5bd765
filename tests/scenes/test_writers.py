"""Writers: a scene written in Blender or nerfstudio format and read back has the same cameras."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from pointfield.clouds.formats.registry import formats
from pointfield.errors import PointfieldError
from pointfield.scenes import Cameras, Scene, convert_scene, look_at, read_scene, write_scene
from pointfield.scenes.scene import Frame


def assert_same_cameras(a: Cameras, b: Cameras) -> None:
    assert a.model == b.model
    for name in ("width", "height"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    for name in ("camera_to_world", "fx", "fy", "cx", "cy", "distortion"):
        assert torch.allclose(getattr(a, name), getattr(b, name), rtol=1e-12, atol=1e-12), name


def in_memory_scene(model="PINHOLE", distortion=None, cx=16.0) -> Scene:
    """Four 32 x 24 views of random colours, two splits."""
    rng = np.random.default_rng(0)
    eyes = np.array([[3.0, 0.0, 1.0], [0.0, 3.0, 1.0], [-3.0, 0.0, 1.0], [0.0, -3.0, 1.0]])
    cameras = Cameras(look_at(eyes), 30.0, 30.0, cx, 12.0, 32, 24, model, distortion)
    frames = [
        Frame(f"view_{i}", image=rng.integers(0, 256, size=(24, 32, 3), dtype=np.uint8)) for i in range(4)
    ]
    return Scene(cameras, frames, {"train": [0, 1, 3], "test": [2]}, near_far=np.tile([1.0, 5.0], (4, 1)))


@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
def test_plain_pinhole_scene_round_trips(tmp_path, fmt):
    scene = in_memory_scene()
    write_scene(scene, tmp_path / "out", fmt)
    back = read_scene(tmp_path / "out")
    assert back.metadata["format"] == fmt
    for split in ("train", "test"):
        assert_same_cameras(scene.split(split).cameras, back.split(split).cameras)
        original, reread = scene.split(split), back.split(split)
        for index in range(len(original)):
            assert np.array_equal(original.image(index), reread.image(index))
    assert back.near_far.tolist() == [[1.0, 5.0]] * 4


@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
def test_distorted_off_centre_cameras_round_trip(tmp_path, fmt):
    scene = in_memory_scene("OPENCV", [0.05, -0.01, 0.001, 0.002, 0.0005], cx=15.3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write_scene(scene, tmp_path / "out", fmt)
    assert (len(caught) == 1) == (fmt == "blender")  # Blender warns that plain loaders ignore the extra keys
    back = read_scene(tmp_path / "out")
    for split in ("train", "test"):
        assert_same_cameras(scene.split(split).cameras, back.split(split).cameras)


def test_fisheye_cameras_round_trip_through_nerfstudio(tmp_path):
    scene = in_memory_scene("OPENCV_FISHEYE", [0.05, -0.01, 0.001, -0.0002])
    write_scene(scene, tmp_path / "out", "nerfstudio")
    document = json.loads((tmp_path / "out/transforms.json").read_text())
    assert document["camera_model"] == "OPENCV_FISHEYE"
    assert_same_cameras(read_scene(tmp_path / "out").cameras, scene.cameras)


def test_nerfstudio_file_has_shared_intrinsics_opengl_poses_and_split_lists(tmp_path):
    scene = in_memory_scene()
    write_scene(scene, tmp_path / "out", "nerfstudio")
    document = json.loads((tmp_path / "out/transforms.json").read_text())
    assert {k: document[k] for k in ("camera_model", "w", "h", "fl_x", "cx")} == {
        "camera_model": "PINHOLE",
        "w": 32,
        "h": 24,
        "fl_x": 30.0,
        "cx": 16.0,
    }
    assert document["test_filenames"] == ["images/view_2.png"]
    pose = np.array(document["frames"][0]["transform_matrix"])
    assert np.allclose(pose[:3, :3] @ np.diag([1, -1, -1]), scene.cameras.rotations[0].numpy())


def test_blender_file_is_plain_for_plain_cameras(tmp_path):
    write_scene(in_memory_scene(), tmp_path / "out", "blender")
    document = json.loads((tmp_path / "out/transforms_train.json").read_text())
    assert set(document) == {"camera_angle_x", "near", "far", "frames"}
    assert document["frames"][0]["file_path"] == "./train/view_0"
    assert (tmp_path / "out/train/view_0.png").is_file()


def test_real_datasets_convert_and_read_back_with_the_same_cameras(tmp_path, shared_data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fox = read_scene(shared_data / "nerf/fox_instant_ngp")
        convert_scene(shared_data / "nerf/fox_instant_ngp", tmp_path / "fox", "nerfstudio")
    assert_same_cameras(fox.cameras, read_scene(tmp_path / "fox").cameras)
    # Images are copied byte for byte when nothing changes them.
    assert (tmp_path / "fox/images/0001.jpg").read_bytes() == (
        shared_data / "nerf/fox_instant_ngp/images/0001.jpg"
    ).read_bytes()
    milk = read_scene(shared_data / "llff/milk")
    convert_scene(shared_data / "llff/milk", tmp_path / "milk", "nerfstudio")
    back = read_scene(tmp_path / "milk")
    assert_same_cameras(milk.cameras, back.cameras)
    assert np.allclose(back.near_far, milk.near_far)
    fixture = read_scene(shared_data / "nerf/lego_test_fixture")
    convert_scene(shared_data / "nerf/lego_test_fixture", tmp_path / "lego", "blender")
    again = read_scene(tmp_path / "lego")
    assert_same_cameras(fixture.cameras, again.cameras)
    assert {name: index.tolist() for name, index in again.splits.items()} == {"train": [0], "val": [1]}


@pytest.mark.skipif("ply" not in {fmt.name for fmt in formats()}, reason="PLY writer not registered")
def test_colmap_points_travel_to_nerfstudio_as_a_ply(tmp_path, shared_data):
    colmap = read_scene(shared_data / "colmap/tiny_phone_scene/sparse/0")
    convert_scene(shared_data / "colmap/tiny_phone_scene/sparse/0", tmp_path / "out")
    back = read_scene(tmp_path / "out")
    assert json.loads((tmp_path / "out/transforms.json").read_text())["ply_file_path"] == "sparse_pc.ply"
    assert np.array_equal(back.points.points, colmap.points.points)
    assert np.array_equal(back.points.fields["colors"], colmap.points.fields["colors"])
    assert_same_cameras(colmap.cameras, back.cameras)


def test_convert_with_downscale_scales_cameras_and_area_averages_images(tmp_path, cube_dataset):
    convert_scene(cube_dataset, tmp_path / "half", "nerfstudio", downscale=2)
    full, half = read_scene(cube_dataset), read_scene(tmp_path / "half")
    assert_same_cameras(full.cameras.scaled(2), half.cameras)
    expected = full.rgba(0).reshape(16, 2, 16, 2, 4).mean(axis=(1, 3))
    assert np.abs(half.rgba(0)[..., 3] - expected[..., 3]).max() <= 0.5 / 255 + 1e-6
    assert half.depth(0).shape == (16, 16) and half.mask(0).shape == (16, 16)


def test_writing_refuses_a_non_empty_folder_unless_overwrite(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "keep.txt").write_text("precious")
    with pytest.raises(PointfieldError, match="not empty"):
        write_scene(in_memory_scene(), target, "nerfstudio")
    assert (target / "keep.txt").read_text() == "precious"
    write_scene(in_memory_scene(), target, "nerfstudio", overwrite=True)
    assert not (target / "keep.txt").exists() and (target / "transforms.json").is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary folders left behind


def test_read_only_formats_are_refused_as_output(tmp_path):
    with pytest.raises(PointfieldError, match="does not write"):
        write_scene(in_memory_scene(), tmp_path / "out", "colmap")


def test_holdout_splits_the_training_frames_and_keeps_val(shared_data):
    scene = read_scene(shared_data / "nerf/lego_test_fixture", holdout_every=2)
    assert {name: index.tolist() for name, index in scene.splits.items()} == {
        "train": [],
        "val": [1],
        "test": [0],
    }
    cube = in_memory_scene()
    with pytest.warns(UserWarning, match="already has a test split"):
        assert cube.with_holdout(2) is cube


def test_split_and_subset_keep_cameras_frames_and_bounds_together():
    scene = in_memory_scene()
    test = scene.split("test")
    assert len(test) == 1 and test.frames[0].name == "view_2"
    assert torch.equal(test.cameras.camera_to_world[0], scene.cameras.camera_to_world[2])
    reordered = scene.subset([3, 0])
    assert [f.name for f in reordered.frames] == ["view_3", "view_0"]
    assert {name: index.tolist() for name, index in reordered.splits.items()} == {"train": [0, 1], "test": []}
    with pytest.raises(PointfieldError, match="no 'val' split"):
        scene.split("val")
