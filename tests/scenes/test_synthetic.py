"""The synthetic ray tracer: exact depth, deterministic files, the lesson's cube, Blender output."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from pointfield.scenes import Cameras, look_at, make_scene, read_scene, render_scene, synthetic_truth
from pointfield.scenes.scene import SceneError
from pointfield.scenes.synthetic import (
    CUBE_FACE_COLORS,
    camera_positions,
    split_indices,
    synthetic_cameras,
    synthetic_scene,
)


def ray_box_distance(origins: np.ndarray, directions: np.ndarray, half: float) -> np.ndarray:
    """Distance to the cube [-half, half]^3 along each ray (inf on a miss), the textbook slab test."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (-half - origins) / directions
        t1 = (half - origins) / directions
    enter = np.minimum(t0, t1).max(axis=-1)
    leave = np.maximum(t0, t1).min(axis=-1)
    return np.where((enter <= leave) & (enter > 0), enter, np.inf)


def test_rendered_depth_equals_the_analytic_ray_box_distance(cube_dataset):
    scene = read_scene(cube_dataset)
    for index in range(len(scene)):
        rays = scene.cameras.rays(index)
        distance = ray_box_distance(rays.origins.numpy(), rays.directions.numpy(), 0.5)
        hit = np.isfinite(distance)
        expected_depth = np.where(hit, distance * rays.axis_cosine.numpy(), 0.0)
        assert np.array_equal(scene.mask(index), hit)
        assert np.allclose(scene.depth(index), expected_depth, rtol=1e-6, atol=0)
        # The cube's silhouette is convex: a pixel whose rays all hit has its centre on the cube,
        # one whose rays all miss does not; only pixels on the silhouette are partly covered.
        alpha = scene.alpha(index)
        assert not np.any((alpha == 1) & ~hit) and not np.any((alpha == 0) & hit)


def test_depth_puts_every_hit_on_the_cube_surface(cube_dataset):
    scene = read_scene(cube_dataset)
    camera_index = 3
    depth, mask = scene.depth(camera_index), scene.mask(camera_index)
    v, u = np.nonzero(mask)
    pixels = torch.from_numpy(np.stack([u + 0.5, v + 0.5], axis=1))
    points = scene.cameras.unproject(
        camera_index, pixels, torch.from_numpy(depth[v, u].astype(np.float64))
    ).numpy()
    assert np.allclose(np.abs(points).max(axis=1), 0.5, atol=1e-5)


def test_making_a_scene_twice_gives_byte_identical_files(tmp_path):
    digests = []
    for attempt in ("first", "second"):
        out = make_scene("still-life", tmp_path / attempt, views=4, size=24)
        files = sorted(p for p in out.rglob("*") if p.is_file())
        digests.append(
            {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}
        )
    assert digests[0] == digests[1]
    assert "transforms_train.json" in digests[0] and "train/r_1_depth.npy" in digests[0]


def test_cube_faces_have_the_lessons_colours():
    """A camera on each axis sees that face in the middle of its image, in the face's hue."""
    axes = np.array([[4, 0, 0], [-4, 0, 0], [0, 4, 0], [0, -4, 0], [0, 0, 4], [0, 0, -4]], dtype=np.float64)
    cameras = Cameras(look_at(axes), 20.0, 20.0, 8.0, 8.0, 16, 16)
    rgba, depth, mask = render_scene("cube", cameras)
    centre = rgba[:, 8, 8, :3]
    for face, color in enumerate(CUBE_FACE_COLORS):
        shade = centre[face] / np.asarray(color, dtype=np.float32)
        assert np.allclose(shade, shade[0], rtol=1e-3), face  # same hue, only the light differs
    assert np.allclose(depth[:, 8, 8], 3.5 * 1.0, atol=1e-6)  # camera at 4, face at 0.5, on the axis
    assert mask[:, 8, 8].all()


def test_hundred_views_split_80_10_10_with_every_tenth_view_for_test():
    splits = split_indices(100)
    assert [len(splits[name]) for name in ("train", "val", "test")] == [80, 10, 10]
    assert splits["test"].tolist() == list(range(0, 100, 10))
    assert splits["val"].tolist() == list(range(5, 100, 10))
    assert {name: index.tolist() for name, index in split_indices(2).items()} == {"train": [0, 1]}
    assert {name: index.tolist() for name, index in split_indices(3).items()} == {
        "train": [2],
        "val": [1],
        "test": [0],
    }


@pytest.mark.parametrize("layout", ["sphere", "hemisphere", "ring"])
def test_camera_layouts_sit_at_the_radius(layout):
    positions = camera_positions(30, 4.0, layout)
    assert np.allclose(np.linalg.norm(positions, axis=1), 4.0)
    if layout != "sphere":
        assert np.all(positions[:, 2] > 0)


def test_made_dataset_reads_back_as_a_blender_scene_with_splits_depth_and_bounds(cube_dataset):
    scene = read_scene(cube_dataset)
    assert scene.metadata["format"] == "blender"
    assert {name: len(index) for name, index in scene.splits.items()} == {"train": 10, "val": 1, "test": 1}
    assert scene.cameras.fx[0].item() == pytest.approx(0.5 * 32 / np.tan(0.5 * 0.6911112070083618))
    assert scene.near_far[0].tolist() == pytest.approx([4 - np.sqrt(3) / 2, 4 + np.sqrt(3) / 2])
    assert np.allclose(scene.aabb, [[-0.6, -0.6, -0.6], [0.6, 0.6, 0.6]])  # the cube with 10 % room
    assert scene.rgba(0).shape == (32, 32, 4)


def test_in_memory_scene_matches_the_written_files(cube_dataset):
    memory = synthetic_scene("cube", views=12, size=32)
    disk = read_scene(cube_dataset)
    position = {frame.image_path.stem: i for i, frame in enumerate(disk.frames)}
    for index, frame in enumerate(memory.frames):
        other = position[frame.name]
        assert np.array_equal(memory.image(index), disk.image(other))
        assert np.array_equal(memory.depth(index), disk.depth(other))
        assert torch.allclose(
            memory.cameras.camera_to_world[index], disk.cameras.camera_to_world[other], atol=1e-15
        )


def test_ground_scenes_have_surfaces_everywhere_the_mask_says():
    scene = synthetic_scene("spheres", views=3, size=24)
    for index in range(len(scene)):
        depth, mask = scene.depth(index), scene.mask(index)
        assert mask.any() and np.all(depth[mask] > 0) and np.all(depth[~mask] == 0)
        assert np.all(depth[mask] <= scene.near_far[index, 1] + 1e-6)


def test_unknown_scene_and_bad_sizes_are_refused(tmp_path):
    with pytest.raises(SceneError, match="unknown synthetic scene"):
        make_scene("teapot", tmp_path / "x", views=3, size=8)
    with pytest.raises(SceneError, match="size"):
        synthetic_scene("cube", views=3, size=0)
    with pytest.raises(SceneError, match="layout"):
        synthetic_scene("cube", views=3, size=8, layout="spiral")


def test_the_textured_scene_is_deterministic_and_full_of_fine_detail():
    first = synthetic_scene("textured", views=3, size=160)
    again = synthetic_scene("textured", views=3, size=160)
    plain = synthetic_scene("still-life", views=3, size=160)
    textured_images = np.stack([first.image(i) for i in range(3)])
    np.testing.assert_array_equal(textured_images, np.stack([again.image(i) for i in range(3)]))

    def detail(images: np.ndarray) -> float:
        """Mean absolute difference between horizontal neighbours: what corners and edges are made of."""
        return float(np.abs(np.diff(images, axis=2)).mean())

    # Twice the plain scene's (2.3 times with 2 x 2 supersampling, which softens every edge alike).
    assert detail(textured_images) > 2.0 * detail(np.stack([plain.image(i) for i in range(3)]))
    # the same surfaces as the still life: textures change colours, not geometry
    np.testing.assert_array_equal(first.mask(0), plain.mask(0))


def test_a_supersampled_pixel_is_the_box_filtered_mean_of_its_rays():
    """2 x 2 rays per pixel give what one ray per pixel gives at twice the size, averaged in 2 x 2
    blocks; depth and mask stay those of the pixel's centre."""
    fine_rgba, _, _ = render_scene("still-life", synthetic_cameras(3, 48), supersampling=1)
    rgba, depth, mask = render_scene("still-life", synthetic_cameras(3, 24), supersampling=2)
    _, centre_depth, centre_mask = render_scene("still-life", synthetic_cameras(3, 24), supersampling=1)

    def blocks(values: np.ndarray) -> np.ndarray:  # (N, 48, 48, ...) -> sums over 2 x 2 blocks
        return values.reshape(3, 24, 2, 24, 2, *values.shape[3:]).sum(axis=(2, 4))

    hits = blocks(fine_rgba[..., 3])
    assert set(np.unique(fine_rgba[..., 3])) == {0.0, 1.0}  # one ray: a pixel is hit or not
    assert np.allclose(rgba[..., 3], hits / 4)
    assert {0.25, 0.5, 0.75} <= set(np.unique(rgba[..., 3]))  # silhouettes are partly covered
    covered = hits > 0
    assert np.allclose(rgba[covered][:, :3], blocks(fine_rgba[..., :3])[covered] / hits[covered, None], atol=1e-5)
    assert np.array_equal(mask, centre_mask) and np.array_equal(depth, centre_depth)


def test_the_textured_cube_is_the_cube_with_detail_on_its_faces():
    textured = synthetic_scene("textured-cube", views=3, size=64)
    plain = synthetic_scene("cube", views=3, size=64)
    for i in range(3):
        # the same surface seen the same way: textures change colours, not geometry
        np.testing.assert_array_equal(textured.mask(i), plain.mask(i))
        np.testing.assert_array_equal(textured.depth(i), plain.depth(i))
    inside = (plain.mask(0)[:, 1:] > 0) & (plain.mask(0)[:, :-1] > 0)

    def detail(image: np.ndarray) -> float:
        """Mean absolute difference between horizontal neighbours on the cube."""
        return float(np.abs(np.diff(image, axis=1))[inside].mean())

    # a plain face is one shade, so only the cube's edges differ from their neighbours
    assert detail(textured.image(0)) > 3 * detail(plain.image(0))


def test_the_command_line_offers_every_synthetic_scene():
    from pointfield.cli.scene import SYNTHETIC_NAMES
    from pointfield.scenes import SYNTHETIC_SCENES

    assert set(SYNTHETIC_NAMES) == set(SYNTHETIC_SCENES)


def test_the_truth_from_a_scenes_own_cameras_is_its_images(cube_dataset):
    scene = read_scene(cube_dataset)
    truth = synthetic_truth(scene, scene.cameras[[0, 3]])
    images = np.stack([scene.image(0), scene.image(3)])
    assert truth.shape == images.shape and float(np.abs(truth - images).max()) <= 1 / 255 + 1e-6  # 8-bit colour and alpha


def test_the_truth_from_a_nearer_camera_shows_the_cube_larger(cube_dataset):
    scene = read_scene(cube_dataset)
    covered = [float((np.abs(synthetic_truth(scene, synthetic_cameras(1, 32, radius=r)) - 1).sum(-1) > 1e-3).mean())
               for r in (4.0, 2.6)]
    assert covered[1] > 1.8 * covered[0]  # the cube's image grows as 1 / distance squared: (4 / 2.6)^2 = 2.4


def test_a_scene_that_is_not_synthetic_has_no_truth_to_render(tmp_path, cube_dataset):
    scene = read_scene(cube_dataset)
    scene.metadata["root"] = str(tmp_path)  # as if read from a folder without synthetic.json
    with pytest.raises(SceneError, match="not a synthetic scene"):
        synthetic_truth(scene, scene.cameras[[0]])
