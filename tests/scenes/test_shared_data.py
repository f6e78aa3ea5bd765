"""Every posed-image dataset in ../shared/data reads as its MANIFEST.md describes, in our convention.

Each reader is checked against something outside pointfield: the dataset's own numbers, the
cameras' known aim (NeRF-synthetic cameras look at the origin), COLMAP's own 2D observations,
and instant-ngp's independent conversion of the same COLMAP model.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from pointfield.errors import FormatError
from pointfield.scenes import read_scene
from pointfield.scenes.formats.colmap import read_colmap_model


@pytest.fixture(scope="module")
def lego(shared_data):
    return read_scene(shared_data / "nerf/lego_blender")


@pytest.fixture(scope="module")
def colmap_scene(shared_data):
    return read_scene(shared_data / "colmap/tiny_phone_scene/sparse/0")


def test_lego_reads_100_frames_of_800x800_with_focal_1111(lego):
    assert len(lego) == 100
    assert lego.metadata["format"] == "blender"
    assert set(lego.cameras.width.tolist()) == {800} and set(lego.cameras.height.tolist()) == {800}
    # f = 0.5 W / tan(0.5 camera_angle_x), camera_angle_x = 0.6911112070083618
    assert lego.cameras.fx[0].item() == pytest.approx(1111.1110311937682, rel=1e-12)
    assert torch.equal(lego.cameras.fx, lego.cameras.fy)
    assert lego.cameras.model == "PINHOLE"
    assert lego.splits["train"].tolist() == list(range(100))
    assert lego.frames[0].image_path.name == "r_0.png"  # extension-less file_path "./train/r_0"
    assert lego.near_far[0].tolist() == [2.0, 6.0]


def test_lego_cameras_converted_from_opengl_look_at_the_origin(lego):
    """NeRF-synthetic cameras aim at the origin: it projects to the image centre, in front (depth > 0)."""
    pixels, depth = lego.cameras.project(torch.zeros(1, 3, dtype=torch.float64))
    assert torch.all(depth > 3.5)
    assert torch.allclose(pixels, torch.full_like(pixels, 400.0), atol=0.01)
    first_pose = np.array(
        [
            [-0.9999021887779236, 0.004192245192825794, -0.013345719315111637, -0.05379832163453102],
            [-0.013988681137561798, -0.2996590733528137, 0.95394366979599, 3.845470428466797],
            [-4.656612873077393e-10, 0.9540371894836426, 0.29968830943107605, 1.2080823183059692],
        ]
    )  # transforms_train.json frame 0, OpenGL
    expected = first_pose * [1, -1, -1, 1]
    # Equal up to the snap to an exact rotation, at the file's float32 precision.
    assert np.allclose(lego.cameras.camera_to_world[0].numpy(), expected, atol=1e-6)


def test_lego_image_loads_composited_on_the_background_and_downscaled(shared_data):
    scene = read_scene(shared_data / "nerf/lego_blender", downscale=8, background="black")
    assert scene.cameras.width[0].item() == 100 and scene.cameras.fx[0].item() == pytest.approx(138.8888789)
    image, alpha = scene.image(0), scene.alpha(0)
    assert image.shape == (100, 100, 3) and image.dtype == np.float32
    assert alpha.shape == (100, 100) and 0 < alpha.mean() < 1
    white = scene.with_background("white").image(0)
    # Compositing is linear in the background: the difference is exactly 1 - alpha.
    assert np.allclose(white - image, (1 - alpha)[..., None], atol=1e-6)


def test_instant_ngp_fox_reads_50_of_67_frames_with_one_warning(shared_data):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fox = read_scene(shared_data / "nerf/fox_instant_ngp")
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "17 of 67 frames" in messages[0]
    assert len(fox) == 50 and fox.metadata["frames_listed"] == 67
    assert fox.metadata["format"] == "nerfstudio"
    assert fox.cameras.model == "OPENCV"
    assert fox.cameras.fx[0].item() == 1375.52 and fox.cameras.fy[0].item() == 1374.49
    assert fox.cameras.distortion[0].tolist() == [0.0578421, -0.0805099, -0.000980296, 0.00015575, 0.0]
    assert (fox.cameras.width[0].item(), fox.cameras.height[0].item()) == (1080, 1920)
    assert all(frame.image_path.is_file() for frame in fox.frames)


def test_fox_cameras_look_at_a_common_point_in_front_of_them(shared_data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fox = read_scene(shared_data / "nerf/fox_instant_ngp")
    _assert_cameras_converge(fox)


def test_llff_milk_reads_43_frames_in_llff_sorted_name_order(shared_data):
    milk = read_scene(shared_data / "llff/milk")
    names = [frame.name for frame in milk.frames]
    assert len(milk) == 43
    assert names == sorted(f"{i}.jpg" for i in range(1, 44))  # lexicographic, as LLFF's loader lists them
    assert names[:3] == ["1.jpg", "10.jpg", "11.jpg"]
    table = np.load(shared_data / "llff/milk/poses_bounds.npy")
    row = table[5, :15].reshape(3, 5)
    down, right, back, centre = row[:, 0], row[:, 1], row[:, 2], row[:, 3]
    expected = np.stack([right, down, -back, centre], axis=1)
    assert np.allclose(milk.cameras.camera_to_world[5].numpy(), expected, atol=1e-12)
    assert milk.near_far[5].tolist() == table[5, 15:].tolist()
    assert milk.cameras.fx[0].item() == pytest.approx(904.639203)
    assert (milk.cameras.width[0].item(), milk.cameras.height[0].item()) == (1140, 855)


def test_llff_cameras_converted_from_down_right_back_look_at_the_object(shared_data):
    _assert_cameras_converge(read_scene(shared_data / "llff/milk"))


def test_llff_holdout_every_8_holds_frames_0_8_16(shared_data):
    milk = read_scene(shared_data / "llff/milk", holdout_every=8)
    assert milk.splits["test"].tolist() == [0, 8, 16, 24, 32, 40]
    assert len(milk.splits["train"]) == 37


def test_colmap_text_and_binary_models_are_identical(shared_data):
    binary = read_scene(shared_data / "colmap/tiny_phone_scene/sparse/0")
    text = read_scene(shared_data / "colmap/tiny_phone_scene/text")
    assert binary.metadata["encoding"] == "binary" and text.metadata["encoding"] == "text"
    assert [f.name for f in binary.frames] == [f.name for f in text.frames] == ["1.jpeg", "2.jpeg", "3.jpeg"]
    for name in ("camera_to_world", "fx", "fy", "cx", "cy", "width", "height", "distortion"):
        assert torch.equal(getattr(binary.cameras, name), getattr(text.cameras, name)), name
    assert np.array_equal(binary.points.points, text.points.points)
    assert np.array_equal(binary.points.fields["colors"], text.points.fields["colors"])
    assert np.array_equal(binary.points.fields["error"], text.points.fields["error"])
    assert len(binary.points) == 256
    binary_model = read_colmap_model(shared_data / "colmap/tiny_phone_scene/sparse/0")
    text_model = read_colmap_model(shared_data / "colmap/tiny_phone_scene/text")
    for image_id, image in binary_model.images.items():
        assert np.array_equal(image.points2d, text_model.images[image_id].points2d)
        assert np.array_equal(image.point3d_ids, text_model.images[image_id].point3d_ids)


def test_colmap_points_reproject_onto_colmaps_own_observations(shared_data, colmap_scene):
    """Pose inversion, OPENCV distortion and the +0.5 pixel convention, checked against COLMAP's 2D points."""
    model = read_colmap_model(shared_data / "colmap/tiny_phone_scene/sparse/0")
    row_of = {point_id: row for row, point_id in enumerate(model.point_ids)}
    frame_of = {frame.name: index for index, frame in enumerate(colmap_scene.frames)}
    for image in model.images.values():
        observed = image.point3d_ids >= 0
        points = model.points[[row_of[i] for i in image.point3d_ids[observed]]]
        pixels, depth = colmap_scene.cameras[frame_of[image.name]].project(torch.from_numpy(points))
        error = np.linalg.norm(pixels[0].numpy() - image.points2d[observed], axis=1)
        assert np.all(depth.numpy() > 0)
        assert np.median(error) < 1.0 and error.max() < 4.0, image.name


def test_colmap_distortion_matters_for_reprojection(shared_data, colmap_scene):
    model = read_colmap_model(shared_data / "colmap/tiny_phone_scene/sparse/0")
    image = model.images[3]
    observed = image.point3d_ids >= 0
    row_of = {point_id: row for row, point_id in enumerate(model.point_ids)}
    points = torch.from_numpy(model.points[[row_of[i] for i in image.point3d_ids[observed]]])
    index = [f.name for f in colmap_scene.frames].index(image.name)
    with_distortion = colmap_scene.cameras[index]
    without = type(with_distortion)(
        with_distortion.camera_to_world,
        with_distortion.fx,
        with_distortion.fy,
        with_distortion.cx,
        with_distortion.cy,
        with_distortion.width,
        with_distortion.height,
    )
    errors = [
        np.median(np.linalg.norm(c.project(points)[0][0].numpy() - image.points2d[observed], axis=1))
        for c in (with_distortion, without)
    ]
    assert errors[0] < errors[1]


def test_colmap_poses_agree_with_instant_ngp_transforms_up_to_one_similarity(shared_data, colmap_scene):
    """colmap2nerf rotated, centred and scaled the world: find that similarity, check every camera."""
    ngp = read_scene(shared_data / "colmap/tiny_phone_scene")  # its transforms.json, OpenGL poses
    assert ngp.metadata["format"] == "nerfstudio"
    row_of = {frame.image_path.name: i for i, frame in enumerate(colmap_scene.frames)}
    order = [row_of[frame.image_path.name] for frame in ngp.frames]
    colmap_centres = colmap_scene.cameras.centers.numpy()[order]
    ngp_centres = ngp.cameras.centers.numpy()
    scale, rotation, translation = umeyama(colmap_centres, ngp_centres)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    moved = scale * colmap_centres @ rotation.T + translation
    assert np.allclose(moved, ngp_centres, atol=1e-9 * scale)
    for k, row in enumerate(order):
        expected = rotation @ colmap_scene.cameras.rotations[row].numpy()
        assert np.allclose(ngp.cameras.rotations[k].numpy(), expected, atol=1e-9), ngp.frames[k].name
        for name in ("fx", "fy", "cx", "cy", "width", "height"):
            assert getattr(ngp.cameras, name)[k].item() == pytest.approx(
                getattr(colmap_scene.cameras, name)[row].item()
            )
    # The same 3D points, moved by the similarity, land on the same pixels in the converted cameras.
    points = torch.from_numpy(scale * colmap_scene.points.points @ rotation.T + translation)
    ngp_pixels, _ = ngp.cameras.project(points)
    colmap_pixels, _ = colmap_scene.cameras[order].project(colmap_scene.points.points)
    visible = torch.isfinite(colmap_pixels).all(-1)
    assert torch.allclose(ngp_pixels[visible], colmap_pixels[visible], atol=1e-6)


def test_nerfstudio_fixture_reads_train_and_val_splits(shared_data):
    scene = read_scene(shared_data / "nerf/lego_test_fixture")
    assert {name: idx.tolist() for name, idx in scene.splits.items()} == {"train": [0], "val": [1]}
    assert scene.cameras.width.tolist() == [50, 50]
    assert scene.image(1).shape == (50, 50, 3)


def test_lego_val_and_test_poses_without_images_or_size_are_refused_with_the_reason(shared_data):
    folder = shared_data / "nerf/lego_splits_meta"
    with pytest.raises(FormatError, match="no frame has its image"):
        read_scene(folder, format="blender")
    with pytest.raises(FormatError, match="size is unknown"):
        read_scene(folder, format="blender", missing_images="keep")


def umeyama(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising |s R source + t - target|^2 (Umeyama 1991)."""
    source_mean, target_mean = source.mean(0), target.mean(0)
    centred_source, centred_target = source - source_mean, target - target_mean
    covariance = centred_target.T @ centred_source / len(source)
    u, singular, vt = np.linalg.svd(covariance)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rotation = u @ sign @ vt
    scale = np.trace(np.diag(singular) @ sign) / (centred_source**2).sum(1).mean()
    return scale, rotation, target_mean - scale * rotation @ source_mean


def _assert_cameras_converge(scene) -> None:
    """The point nearest every optical axis is in front of every camera and inside every image."""
    centres = scene.cameras.centers.numpy()
    axes = scene.cameras.rotations[:, :, 2].numpy()
    projectors = np.eye(3) - axes[:, :, None] * axes[:, None, :]
    target = np.linalg.solve(projectors.sum(0), np.einsum("nij,nj->i", projectors, centres))
    pixels, depth = scene.cameras.project(torch.from_numpy(target[None]))
    assert torch.all(depth > 0)
    assert torch.all((pixels[..., 0] > 0) & (pixels[..., 0] < scene.cameras.width[:, None]))
    assert torch.all((pixels[..., 1] > 0) & (pixels[..., 1] < scene.cameras.height[:, None]))


@pytest.mark.parametrize(
    "dataset, fmt",
    [
        ("nerf/lego_blender", None),
        ("nerf/fox_instant_ngp", None),
        ("llff/milk", None),
        ("colmap/tiny_phone_scene/sparse/0", None),
        ("colmap/tiny_phone_scene/text", None),
        ("colmap/tiny_phone_scene", "nerfstudio"),
    ],
)
def test_a_point_on_a_pixels_ray_projects_back_to_that_pixel_for_every_reader(shared_data, dataset, fmt):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = read_scene(shared_data / dataset, fmt)
    rng = np.random.default_rng(0)
    for index in rng.choice(len(scene), size=min(3, len(scene)), replace=False):
        width, height = int(scene.cameras.width[index]), int(scene.cameras.height[index])
        u, v = rng.integers(0, width, size=50), rng.integers(0, height, size=50)
        centres = torch.from_numpy(np.stack([u + 0.5, v + 0.5], axis=1).astype(np.float64))
        rays = scene.cameras.rays_through(torch.tensor(int(index)), centres)
        distance = torch.from_numpy(rng.uniform(0.5, 5.0, size=50))
        pixels, depth = scene.cameras[int(index)].project(rays.at(distance))
        assert torch.allclose(pixels[0], centres, atol=1e-6)
        assert torch.allclose(depth[0], distance * rays.axis_cosine)
