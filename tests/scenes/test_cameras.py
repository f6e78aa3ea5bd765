"""Cameras and rays: the one internal convention (OpenCV), projection, distortion, devices."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pointfield.scenes import Cameras, look_at, opencv_to_opengl, opengl_to_opencv, pixel_centers
from pointfield.scenes.cameras import distort_opencv, undistort_fisheye_angle, undistort_opencv


def front_camera(model="PINHOLE", distortion=None, width=64, height=48) -> Cameras:
    """One camera at (0, -4, 0) looking at the origin, world z up in the image."""
    return Cameras(look_at([[0.0, -4.0, 0.0]]), 50.0, 55.0, 30.0, 25.0, width, height, model, distortion)


def random_cameras(count=5, model="PINHOLE", distortion=None, seed=0) -> Cameras:
    rng = np.random.default_rng(seed)
    eyes = rng.normal(size=(count, 3))
    eyes = 3 * eyes / np.linalg.norm(eyes, axis=1, keepdims=True)
    targets = rng.normal(scale=0.3, size=3)
    return Cameras(look_at(eyes, targets), 70.0, 72.0, 33.0, 22.5, 64, 48, model, distortion)


def test_look_at_gives_opencv_axes_right_down_forward():
    pose = look_at([[0.0, -4.0, 0.0]])[0]
    right, down, forward, centre = pose.T
    assert torch.allclose(forward, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    assert torch.allclose(right, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    assert torch.allclose(down, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    assert torch.allclose(centre, torch.tensor([0.0, -4.0, 0.0], dtype=torch.float64))
    assert torch.det(pose[:, :3]) == pytest.approx(1.0)


def test_look_at_straight_down_the_up_axis_is_still_a_rotation():
    pose = look_at([[0.0, 0.0, 5.0]])[0]
    rotation = pose[:, :3]
    assert torch.allclose(rotation.T @ rotation, torch.eye(3, dtype=torch.float64))
    assert torch.allclose(pose[:, 2], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))


def test_opengl_to_opencv_flips_y_and_z_columns_and_is_its_own_inverse():
    gl = np.eye(4)
    gl[:3, 3] = [1.0, 2.0, 3.0]
    cv = opengl_to_opencv(gl)
    assert np.array_equal(cv[:3, :3], np.diag([1.0, -1.0, -1.0]))
    assert np.array_equal(cv[:3, 3], gl[:3, 3])
    assert np.array_equal(opencv_to_opengl(cv), gl)
    assert torch.equal(opengl_to_opencv(torch.from_numpy(gl)), torch.from_numpy(cv))


def test_opengl_camera_looks_down_minus_z_and_opencv_down_plus_z():
    """The same physical camera in both conventions sees the origin in front of it."""
    gl_pose = np.eye(4)
    gl_pose[:3, 3] = [0.0, 0.0, 4.0]  # OpenGL camera at +4 z looking down -z, towards the origin
    cameras = Cameras(opengl_to_opencv(gl_pose), 50.0, 50.0, 32.0, 24.0, 64, 48)
    pixels, depth = cameras.project(torch.zeros(1, 3, dtype=torch.float64))
    assert depth.item() == pytest.approx(4.0)
    assert pixels[0, 0].tolist() == pytest.approx([32.0, 24.0])
    # World +y is up for the OpenGL camera, so a point above the origin lands above the centre.
    pixels_up, _ = cameras.project(torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64))
    assert pixels_up[0, 0, 1] < 24.0


def test_pixel_centers_are_at_half_integers_indexed_row_column():
    grid = pixel_centers(3, 2)
    assert grid.shape == (2, 3, 2)
    assert grid[0, 0].tolist() == [0.5, 0.5]
    assert grid[1, 2].tolist() == [2.5, 1.5]


def test_rays_cover_every_pixel_in_image_layout_with_unit_directions():
    cameras = random_cameras(count=3)
    rays = cameras.rays()
    assert rays.shape == (3, 48, 64)
    assert rays.origins.shape == (3, 48, 64, 3)
    assert torch.allclose(rays.directions.norm(dim=-1), torch.ones(3, 48, 64, dtype=torch.float64))
    assert torch.allclose(rays.origins[1, 5, 7], cameras.centers[1])
    assert torch.equal(cameras.rays(2).directions, rays.directions[2])


def test_ray_of_a_pixel_passes_through_its_centre():
    cameras = front_camera()
    rays = cameras.rays(0)
    v, u = 10, 40
    camera_frame = cameras.rotations[0].T @ rays.directions[v, u]
    x, y = (camera_frame[:2] / camera_frame[2]).tolist()
    assert 50.0 * x + 30.0 == pytest.approx(u + 0.5)
    assert 55.0 * y + 25.0 == pytest.approx(v + 0.5)


def test_axis_cosine_turns_ray_distance_into_z_depth():
    cameras = random_cameras(count=2)
    rays = cameras.rays()
    points = rays.at(torch.full(rays.shape, 2.5, dtype=torch.float64))
    _, depth = cameras.project(points.reshape(2, -1, 3))
    assert torch.allclose(depth, (2.5 * rays.axis_cosine).reshape(2, -1))


@pytest.mark.parametrize(
    "model, distortion",
    [
        ("PINHOLE", None),
        ("OPENCV", [0.05, -0.02, 0.001, -0.002, 0.003]),
        ("OPENCV", [-0.3, 0.1, 0.0, 0.0, 0.0]),
        ("OPENCV_FISHEYE", [0.05, -0.01, 0.002, -0.0005]),
    ],
)
def test_known_point_projects_to_the_pixel_whose_ray_passes_through_it(model, distortion):
    cameras = random_cameras(count=4, model=model, distortion=distortion)
    rng = np.random.default_rng(1)
    pixels = torch.from_numpy(rng.uniform([0, 0], [64, 48], size=(4, 50, 2)))
    depth = torch.from_numpy(rng.uniform(0.5, 6.0, size=(4, 50)))
    camera_index = torch.arange(4)[:, None].expand(-1, 50)
    points = cameras.unproject(camera_index, pixels, depth)
    projected, projected_depth = cameras.project(points)
    assert torch.allclose(projected, pixels, atol=1e-8)
    assert torch.allclose(projected_depth, depth, atol=1e-10)


def test_undistort_inverts_distort():
    rng = np.random.default_rng(2)
    points = torch.from_numpy(rng.uniform(-0.6, 0.6, size=(1000, 2)))
    coefficients = torch.tensor([0.0578, -0.0805, -0.00098, 0.000156, 0.01], dtype=torch.float64).expand(
        1000, 5
    )
    assert torch.allclose(
        undistort_opencv(distort_opencv(points, coefficients), coefficients), points, atol=1e-12
    )


def test_fisheye_rays_reach_past_ninety_degrees():
    """An equidistant fisheye (no k) maps theta = r_d; a pixel 100 degrees out gets a ray behind the image plane."""
    cameras = Cameras(look_at([[0.0, -4.0, 0.0]]), 100.0, 100.0, 200.0, 200.0, 400, 400, "OPENCV_FISHEYE")
    theta = math.radians(100)
    rays = cameras.rays_through(0, torch.tensor([[200.0 + 100.0 * theta, 200.0]], dtype=torch.float64))
    assert rays.axis_cosine.item() == pytest.approx(math.cos(theta))
    angle = undistort_fisheye_angle(
        torch.tensor([theta], dtype=torch.float64), torch.zeros(1, 4, dtype=torch.float64)
    )
    assert angle.item() == pytest.approx(theta)


def test_points_behind_a_perspective_camera_project_to_nan():
    cameras = front_camera()
    pixels, depth = cameras.project(torch.tensor([[0.0, -8.0, 0.0]], dtype=torch.float64))
    assert depth.item() < 0
    assert torch.isnan(pixels).all()


def test_view_and_intrinsic_matrices_agree_with_project():
    cameras = random_cameras(count=3)
    points = torch.randn(20, 3, dtype=torch.float64) * 0.5
    homogeneous = torch.cat([points, torch.ones(20, 1, dtype=torch.float64)], dim=1)
    in_camera = torch.einsum("nij,pj->npi", cameras.world_to_camera(), homogeneous)[..., :3]
    image = torch.einsum("nij,npj->npi", cameras.intrinsic_matrices(), in_camera)
    pixels, depth = cameras.project(points)
    assert torch.allclose(image[..., :2] / image[..., 2:], pixels)
    assert torch.allclose(in_camera[..., 2], depth)


def test_scaled_cameras_see_the_same_point_at_scaled_coordinates():
    cameras = random_cameras(count=2)
    half = cameras.scaled(2)
    assert half.width.tolist() == [32, 32] and half.height.tolist() == [24, 24]
    point = torch.tensor([[0.1, 0.2, -0.1]], dtype=torch.float64)
    assert torch.allclose(half.project(point)[0], cameras.project(point)[0] / 2)


def test_indexing_and_concatenation_keep_every_field():
    cameras = random_cameras(count=5, model="OPENCV", distortion=[0.1, 0.0, 0.0, 0.0, 0.0])
    picked = cameras[[4, 0]]
    assert len(picked) == 2 and picked.model == "OPENCV"
    assert torch.equal(picked.camera_to_world[0], cameras.camera_to_world[4])
    assert len(cameras[-1]) == 1 and torch.equal(cameras[-1].centers, cameras.centers[4:])
    joined = Cameras.cat([cameras[:2], cameras[2:]])
    assert torch.equal(joined.camera_to_world, cameras.camera_to_world)
    assert torch.equal(joined.distortion, cameras.distortion)


def test_to_changes_dtype_and_rays_follow_the_cameras():
    cameras = random_cameras(count=2).to("cpu", torch.float32)
    assert cameras.dtype == torch.float32 and cameras.width.dtype == torch.int64
    rays = cameras.rays(0)
    assert rays.directions.dtype == torch.float32 and rays.directions.device.type == "cpu"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_rays_are_generated_on_the_cameras_cuda_device():
    cameras = random_cameras(count=2, model="OPENCV", distortion=[0.05, 0.0, 0.0, 0.0, 0.0])
    on_gpu = cameras.to("cuda")
    rays = on_gpu.rays()
    assert rays.origins.device.type == "cuda"
    assert torch.allclose(rays.directions.cpu(), cameras.rays().directions, atol=1e-12)


def test_repr_names_count_model_size_and_focal():
    assert repr(front_camera()) == "Cameras(1, PINHOLE, 64x48, fx 50, torch.float64, cpu)"
