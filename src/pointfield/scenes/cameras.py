"""Cameras and rays, in pointfield's one internal camera convention (OpenCV / COLMAP).

Every reader converts its dataset to this convention at the edge, so nothing downstream ever
asks "is this OpenGL or OpenCV?".

The convention
--------------
Camera frame
    x to the right, y down, z forward: the camera looks down its +z axis (OpenCV, COLMAP, gsplat).
    OpenGL / Blender / nerfstudio / instant-ngp cameras are x right, y up, looking down -z; a pose
    in that convention becomes ours by negating its y and z columns,
    ``c2w_opencv = c2w_opengl @ diag(1, -1, -1, 1)`` (:func:`opengl_to_opencv`).
Poses
    ``camera_to_world`` is ``(N, 3, 4)`` ``[R | C]``: the columns of R are the camera's x, y, z
    axes written in world coordinates and C is the camera centre, so a point maps to the world by
    ``X_world = R @ X_camera + C``. World-to-camera ("view") matrices, as gsplat takes them, are
    ``[R^T | -R^T C]`` (:meth:`Cameras.world_to_camera`). World units are the dataset's own.
Pixels
    Continuous pixel coordinates (x, y), x to the right and y down, with the origin at the
    top-left *corner* of the image: pixel (u, v) -- column u, row v -- covers
    ``[u, u + 1) x [v, v + 1)`` and its centre is ``(u + 0.5, v + 0.5)``. This is COLMAP's,
    nerfstudio's, instant-ngp's and gsplat's convention; OpenCV puts pixel centres on integers
    (``cx_opencv = cx - 0.5``). An image array is indexed ``image[v, u]``.
Projection
    A camera-frame point (X, Y, Z) with Z > 0 has normalised coordinates ``(x, y) = (X/Z, Y/Z)``,
    distorted coordinates ``(x_d, y_d) = distort(x, y)``, and pixel
    ``(fx * x_d + cx, fy * y_d + cy)``.
Camera models (COLMAP / nerfstudio names)
    ``PINHOLE``
        no distortion.
    ``OPENCV``
        radial-tangential, coefficients (k1, k2, p1, p2, k3), r^2 = x^2 + y^2:
        ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)``,
        ``y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y``.
    ``OPENCV_FISHEYE``
        equidistant fisheye, coefficients (k1, k2, k3, k4), theta = atan(r):
        ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
        ``(x_d, y_d) = (theta_d / r) (x, y)``.

    Undistortion (pixel -> ray) has no closed form; it runs Newton iterations (at most 10, until
    every step is below 1e-12) and is that exact where the distortion polynomial is monotonic.
Rays
    :class:`Rays` hold world-space origins (the camera centre), **unit** directions, and
    ``axis_cosine``, the cosine between each ray and its camera's optical axis. A point at
    distance t along a ray has z-depth (distance along the optical axis, what depth maps store)
    ``t * axis_cosine``; renderers that report depth maps multiply by it.
Precision and devices
    Cameras hold torch tensors; rays are generated on the cameras' device in their dtype. Readers
    produce float64 so that poses read back exactly; call ``cameras.to(device, torch.float32)``
    before heavy work on a GPU. MPS has no float64, so ``.to("mps")`` converts to float32.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

CAMERA_MODELS: dict[str, tuple[str, ...]] = {
    "PINHOLE": (),
    "OPENCV": ("k1", "k2", "p1", "p2", "k3"),
    "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4"),
}
"""Camera model name -> names of its distortion coefficients, in the order they are stored."""

UNDISTORT_ITERATIONS = 10
"""Most Newton iterations used to invert the distortion; quadratic convergence makes 10 plenty."""


def opengl_to_opencv(camera_to_world):
    """Convert OpenGL / Blender camera-to-world poses (x right, y up, looking down -z) to ours.

    ``c2w_opencv = c2w_opengl @ diag(1, -1, -1, 1)``: the camera's y and z axes flip, its centre
    stays. Works on numpy arrays or torch tensors of shape ``(..., 3, 4)`` or ``(..., 4, 4)``
    and returns a new array of the same kind.
    """
    flipped = (
        camera_to_world.clone() if torch.is_tensor(camera_to_world) else np.array(camera_to_world, copy=True)
    )
    flipped[..., :3, 1:3] *= -1
    return flipped


def opencv_to_opengl(camera_to_world):
    """Convert our (OpenCV) camera-to-world poses to OpenGL / Blender ones.

    The flip is its own inverse, so this is :func:`opengl_to_opencv` under the name that says
    which way the data goes.
    """
    return opengl_to_opencv(camera_to_world)


def look_at(eyes, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """Camera-to-world poses ``(N, 3, 4)`` float64 of cameras at ``eyes`` ``(N, 3)`` looking at ``target``.

    OpenCV axes: z = forward = normalise(target - eye), x = right = normalise(z x up),
    y = down = z x x. ``up`` is the world direction that appears up in the image; a camera looking
    straight along it uses the world x axis instead, so every eye gives a valid pose.
    """
    eyes = torch.as_tensor(np.asarray(eyes, dtype=np.float64)).reshape(-1, 3)
    target = torch.as_tensor(np.asarray(target, dtype=np.float64)).reshape(3)
    up = torch.as_tensor(np.asarray(up, dtype=np.float64)).reshape(3).expand_as(eyes).clone()
    forward = torch.nn.functional.normalize(target - eyes, dim=-1)
    parallel = torch.linalg.cross(forward, up).norm(dim=-1) < 1e-9
    up[parallel] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    right = torch.nn.functional.normalize(torch.linalg.cross(forward, up), dim=-1)
    down = torch.linalg.cross(forward, right)
    return torch.stack([right, down, forward, eyes], dim=-1)


def pixel_centers(width: int, height: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """Continuous coordinates of every pixel centre, ``(H, W, 2)``: ``[v, u] = (u + 0.5, v + 0.5)``."""
    u = torch.arange(width, device=device, dtype=dtype) + 0.5
    v = torch.arange(height, device=device, dtype=dtype) + 0.5
    grid_v, grid_u = torch.meshgrid(v, u, indexing="ij")
    return torch.stack([grid_u, grid_v], dim=-1)


@dataclass
class Rays:
    """A bundle of world-space rays of any batch shape ``S``.

    ``origins`` ``S + (3,)`` camera centres; ``directions`` ``S + (3,)`` unit vectors;
    ``axis_cosine`` ``S``: cosine between each ray and its camera's optical axis, so a point at
    distance t along the ray lies at z-depth ``t * axis_cosine``.
    """

    origins: torch.Tensor
    directions: torch.Tensor
    axis_cosine: torch.Tensor

    @property
    def shape(self) -> torch.Size:
        """The batch shape ``S`` (without the trailing 3)."""
        return self.axis_cosine.shape

    def reshape(self, *shape: int) -> Rays:
        """The same rays with batch shape ``shape`` (e.g. ``rays.reshape(-1)`` to flatten)."""
        return Rays(
            self.origins.reshape(*shape, 3),
            self.directions.reshape(*shape, 3),
            self.axis_cosine.reshape(*shape),
        )

    def __getitem__(self, index) -> Rays:
        return Rays(self.origins[index], self.directions[index], self.axis_cosine[index])

    def to(self, device=None, dtype=None) -> Rays:
        return Rays(
            self.origins.to(device, dtype),
            self.directions.to(device, dtype),
            self.axis_cosine.to(device, dtype),
        )

    def at(self, distance: torch.Tensor) -> torch.Tensor:
        """Points ``origins + distance * directions``; ``distance`` has shape ``S`` or ``S + (K,)``.

        With ``S + (K,)`` (K samples per ray, as a NeRF sampler makes) the result is ``S + (K, 3)``.
        """
        if distance.shape == self.shape:
            return self.origins + distance[..., None] * self.directions
        return self.origins[..., None, :] + distance[..., None] * self.directions[..., None, :]


class Cameras:
    """N cameras: intrinsics, distortion and camera-to-world poses, as torch tensors.

    Arguments (scalars broadcast to all N cameras):

    - ``camera_to_world``: ``(N, 3, 4)`` or ``(N, 4, 4)`` (or one ``(3, 4)`` / ``(4, 4)``), OpenCV
      convention (see the module docstring). Only the top three rows are kept.
    - ``fx``, ``fy``, ``cx``, ``cy``: ``(N,)`` focal lengths and principal point in pixels.
    - ``width``, ``height``: ``(N,)`` image size in pixels (int64).
    - ``model``: one of :data:`CAMERA_MODELS` for the whole batch.
    - ``distortion``: ``(N, K)`` coefficients in the order :data:`CAMERA_MODELS` lists
      (K = 0 for PINHOLE, 5 for OPENCV, 4 for OPENCV_FISHEYE); zeros when omitted.

    Floating tensors take ``camera_to_world``'s dtype (float64 when it is given as a numpy float64
    array or a list) and device.

    Example::

        >>> cams = Cameras(look_at([[0.0, -4.0, 0.0]]), fx=100.0, fy=100.0, cx=50.0, cy=50.0,
        ...                width=100, height=100)
        >>> cams.rays(0).shape
        torch.Size([100, 100])
        >>> cams.project(torch.zeros(1, 3, dtype=torch.float64))[0]
        tensor([[[50., 50.]]], dtype=torch.float64)
    """

    def __init__(
        self,
        camera_to_world,
        fx,
        fy,
        cx,
        cy,
        width,
        height,
        model: str = "PINHOLE",
        distortion=None,
    ):
        poses = torch.as_tensor(camera_to_world)
        if not poses.is_floating_point():
            poses = poses.to(torch.float64)
        if poses.ndim == 2:
            poses = poses[None]
        if poses.ndim != 3 or poses.shape[-1] != 4 or poses.shape[-2] not in (3, 4):
            raise ValueError(f"camera_to_world must be (N, 3, 4) or (N, 4, 4), got {tuple(poses.shape)}")
        self.camera_to_world = poses[:, :3, :].contiguous()
        count = len(self.camera_to_world)
        float_kind = {"dtype": poses.dtype, "device": poses.device}
        int_kind = {"dtype": torch.int64, "device": poses.device}
        self.fx = _per_camera(fx, count, "fx", float_kind)
        self.fy = _per_camera(fy, count, "fy", float_kind)
        self.cx = _per_camera(cx, count, "cx", float_kind)
        self.cy = _per_camera(cy, count, "cy", float_kind)
        self.width = _per_camera(width, count, "width", int_kind)
        self.height = _per_camera(height, count, "height", int_kind)
        if model not in CAMERA_MODELS:
            raise ValueError(f"camera model must be one of {', '.join(CAMERA_MODELS)}, got {model!r}")
        self.model = model
        coefficients = len(CAMERA_MODELS[model])
        given = (
            torch.zeros(count, coefficients, **float_kind)
            if distortion is None
            else torch.as_tensor(distortion, **float_kind)
        )
        if given.numel() not in (coefficients, count * coefficients):
            raise ValueError(
                f"{model} takes {coefficients} distortion coefficients per camera, got {tuple(given.shape)}"
            )
        # reshape(-1, 0) is ambiguous, so cameras without coefficients get an explicit (N, 0).
        self.distortion = (
            given.reshape(-1, coefficients).expand(count, coefficients).contiguous()
            if coefficients
            else torch.zeros(count, 0, **float_kind)
        )

    # -- batch bookkeeping -------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.camera_to_world)

    def __getitem__(self, index) -> Cameras:
        """The cameras picked by an int, slice, index array or boolean mask (always a batch)."""
        if isinstance(index, (int, np.integer)):
            index = int(index) % len(self)
            index = slice(index, index + 1)
        elif not isinstance(index, slice):
            index = torch.as_tensor(np.asarray(index), device=self.device)
        return Cameras(
            self.camera_to_world[index],
            self.fx[index],
            self.fy[index],
            self.cx[index],
            self.cy[index],
            self.width[index],
            self.height[index],
            self.model,
            self.distortion[index],
        )

    @property
    def device(self) -> torch.device:
        return self.camera_to_world.device

    @property
    def dtype(self) -> torch.dtype:
        return self.camera_to_world.dtype

    def to(self, device=None, dtype: torch.dtype | None = None) -> Cameras:
        """The cameras on ``device`` in floating ``dtype``; MPS gets float32 since it has no float64."""
        device = torch.device(device) if device is not None else self.device
        dtype = dtype or self.dtype
        if device.type == "mps" and dtype == torch.float64:
            dtype = torch.float32
        return Cameras(
            self.camera_to_world.to(device, dtype),
            self.fx.to(device, dtype),
            self.fy.to(device, dtype),
            self.cx.to(device, dtype),
            self.cy.to(device, dtype),
            self.width.to(device),
            self.height.to(device),
            self.model,
            self.distortion.to(device, dtype),
        )

    def scaled(self, factor: int) -> Cameras:
        """The cameras of images downscaled by an integer ``factor`` (area resampling).

        Output pixel u covers input pixels ``[f u, f u + f)``, so continuous coordinates divide by
        f: ``fx / f``, ``cx / f``, ...; the size is ``width // f`` (a partial block at the right or
        bottom edge is dropped, which moves no coordinate).
        """
        if int(factor) != factor or factor < 1:
            raise ValueError(f"downscale factor must be a positive integer, got {factor}")
        factor = int(factor)
        return Cameras(
            self.camera_to_world,
            self.fx / factor,
            self.fy / factor,
            self.cx / factor,
            self.cy / factor,
            self.width // factor,
            self.height // factor,
            self.model,
            self.distortion,
        )

    @staticmethod
    def cat(batches: Sequence[Cameras]) -> Cameras:
        """One batch of the cameras of several batches (all of one model), in order."""
        models = {batch.model for batch in batches}
        if len(models) != 1:
            raise ValueError(f"cannot concatenate cameras of different models {sorted(models)}")
        return Cameras(
            torch.cat([b.camera_to_world for b in batches]),
            torch.cat([b.fx for b in batches]),
            torch.cat([b.fy for b in batches]),
            torch.cat([b.cx for b in batches]),
            torch.cat([b.cy for b in batches]),
            torch.cat([b.width for b in batches]),
            torch.cat([b.height for b in batches]),
            models.pop(),
            torch.cat([b.distortion for b in batches]),
        )

    def __repr__(self) -> str:
        sizes = sorted({(int(w), int(h)) for w, h in zip(self.width, self.height)})
        size = f"{sizes[0][0]}x{sizes[0][1]}" if len(sizes) == 1 else f"{len(sizes)} sizes"
        focal = f"fx {float(self.fx[0]):.6g}" if len(self) else "empty"
        return f"Cameras({len(self)}, {self.model}, {size}, {focal}, {self.dtype}, {self.device})"

    # -- geometry -----------------------------------------------------------------------------

    @property
    def centers(self) -> torch.Tensor:
        """Camera centres in world coordinates, ``(N, 3)``."""
        return self.camera_to_world[:, :, 3]

    @property
    def rotations(self) -> torch.Tensor:
        """Camera-to-world rotations ``(N, 3, 3)``; column k is camera axis k in the world."""
        return self.camera_to_world[:, :, :3]

    def axes_focus(self) -> tuple[np.ndarray, bool]:
        """The point nearest every camera's optical axis, float64 ``(3,)``, and whether the axes pin it down.

        Least squares: minimises ``sum_i |(I - a_i a_i^T)(p - c_i)|^2`` over p, with ``c_i`` the
        centres and ``a_i`` the viewing directions (+z, OpenCV). Nearly parallel axes -- a
        forward-facing capture -- meet nowhere in particular: then the second value is False
        (the normal matrix's smallest singular value is under 5 % of its largest) and the point,
        the least-norm solution, should not be relied on.
        """
        centres = self.centers.double().cpu().numpy()
        axes = self.rotations[:, :, 2].double().cpu().numpy()
        projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
        normal = projectors.sum(0)
        point = np.linalg.lstsq(normal, np.einsum("nij,nj->i", projectors, centres), rcond=None)[0]
        singular = np.linalg.svd(normal, compute_uv=False)
        return point, bool(singular[-1] >= 0.05 * singular[0])

    def world_to_camera(self) -> torch.Tensor:
        """World-to-camera view matrices ``(N, 4, 4)``, ``[R^T | -R^T C; 0 0 0 1]`` (gsplat's ``viewmats``)."""
        rotation_t = self.rotations.transpose(1, 2)
        view = torch.zeros(len(self), 4, 4, dtype=self.dtype, device=self.device)
        view[:, :3, :3] = rotation_t
        view[:, :3, 3] = -(rotation_t @ self.centers[:, :, None])[:, :, 0]
        view[:, 3, 3] = 1
        return view

    def intrinsic_matrices(self) -> torch.Tensor:
        """``(N, 3, 3)`` matrices ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (gsplat's ``Ks``)."""
        matrix = torch.zeros(len(self), 3, 3, dtype=self.dtype, device=self.device)
        matrix[:, 0, 0] = self.fx
        matrix[:, 1, 1] = self.fy
        matrix[:, 0, 2] = self.cx
        matrix[:, 1, 2] = self.cy
        matrix[:, 2, 2] = 1
        return matrix

    def rays(self, index: int | None = None) -> Rays:
        """Rays through the centre of every pixel: ``(H, W)`` for camera ``index``, else ``(N, H, W)``.

        Ray ``[v, u]`` passes through pixel centre ``(u + 0.5, v + 0.5)``, so it matches
        ``image[v, u]``. Without an index all cameras must share one image size.
        """
        if index is not None:
            index = int(index) % len(self)
            grid = pixel_centers(
                int(self.width[index]), int(self.height[index]), device=self.device, dtype=self.dtype
            )
            return self.rays_through(torch.tensor(index, device=self.device), grid)
        sizes = {(int(w), int(h)) for w, h in zip(self.width, self.height)}
        if len(sizes) != 1:
            raise ValueError(
                f"cameras have {len(sizes)} different image sizes; ask for rays one camera at a time"
            )
        width, height = sizes.pop()
        grid = pixel_centers(width, height, device=self.device, dtype=self.dtype)
        return self.rays_through(torch.arange(len(self), device=self.device)[:, None, None], grid)

    def rays_through(self, camera_index, pixels: torch.Tensor) -> Rays:
        """Rays of cameras ``camera_index`` through continuous ``pixels`` ``S + (2,)``.

        ``camera_index`` is an int tensor broadcastable to ``S`` (a single index for one camera).
        This is the sampler's entry point: pick random cameras and pixels, get their rays.
        Pixel centres are at ``+ 0.5`` (see the module docstring).
        """
        camera_index = torch.as_tensor(camera_index, device=self.device)
        pixels = torch.as_tensor(pixels, device=self.device, dtype=self.dtype)
        x = (pixels[..., 0] - self.cx[camera_index]) / self.fx[camera_index]
        y = (pixels[..., 1] - self.cy[camera_index]) / self.fy[camera_index]
        x, y = torch.broadcast_tensors(x, y)
        directions_camera = self._directions_from_normalized(x, y, self.distortion[camera_index])
        rotation = self.rotations[camera_index]
        # Rotated with R (..., 3, 3) broadcast over the pixels of each camera; normalised again
        # in case a caller's poses are orthonormal only to their printed precision.
        directions = torch.nn.functional.normalize((rotation @ directions_camera[..., None])[..., 0], dim=-1)
        origins = self.centers[camera_index].expand_as(directions)
        return Rays(origins, directions, directions_camera[..., 2])

    def project(self, points) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixels and z-depths of world ``points`` in every camera.

        ``points`` is ``(P, 3)`` (the same points for every camera) or ``(N, P, 3)``; returns
        pixels ``(N, P, 2)`` in continuous coordinates and depths ``(N, P)`` along each optical
        axis. Points a camera cannot see geometrically (behind a perspective camera, beyond 180
        degrees of a fisheye) get NaN pixels; points outside the image keep their coordinates.
        """
        points = torch.as_tensor(points, device=self.device, dtype=self.dtype)
        if points.ndim == 2:
            points = points.expand(len(self), -1, -1)
        # X_camera = R^T (X - C), written for row vectors.
        camera_points = (points - self.centers[:, None, :]) @ self.rotations
        depth = camera_points[..., 2]
        coefficients = self.distortion[:, None, :].expand(-1, points.shape[1], -1)
        if self.model == "OPENCV_FISHEYE":
            radius = camera_points[..., :2].norm(dim=-1)
            theta = torch.atan2(radius, depth)
            theta_distorted = _fisheye_polynomial(theta, coefficients)
            # theta_d / r tends to 1 / z on the axis; clamp_min keeps the centre finite.
            scale = torch.where(radius > 0, theta_distorted / radius.clamp_min(1e-300), 1 / depth)
            distorted = camera_points[..., :2] * scale[..., None]
            visible = theta < torch.pi
        else:
            normalized = camera_points[..., :2] / depth[..., None]
            distorted = distort_opencv(normalized, coefficients) if self.model == "OPENCV" else normalized
            visible = depth > 0
        pixel_x = self.fx[:, None] * distorted[..., 0] + self.cx[:, None]
        pixel_y = self.fy[:, None] * distorted[..., 1] + self.cy[:, None]
        pixels = torch.stack([pixel_x, pixel_y], dim=-1)
        pixels = torch.where(visible[..., None], pixels, torch.full_like(pixels, torch.nan))
        return pixels, depth

    def unproject(self, camera_index, pixels: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """World points at z-depth ``depth`` ``S`` behind ``pixels`` ``S + (2,)`` of cameras ``camera_index``.

        The inverse of :meth:`project`: ``origin + direction * depth / axis_cosine``.
        """
        rays = self.rays_through(camera_index, pixels)
        depth = torch.as_tensor(depth, device=self.device, dtype=self.dtype)
        return rays.at(depth / rays.axis_cosine)

    def _directions_from_normalized(
        self, x: torch.Tensor, y: torch.Tensor, coefficients: torch.Tensor
    ) -> torch.Tensor:
        """Unit camera-frame directions of distorted normalised coordinates ``(x, y)``, ``S + (3,)``."""
        distorted = torch.stack([x, y], dim=-1)
        if self.model == "OPENCV_FISHEYE":
            theta_distorted = distorted.norm(dim=-1)
            theta = undistort_fisheye_angle(theta_distorted, coefficients)
            # Built from the angle rather than (x, y, 1) so rays past 90 degrees stay correct.
            in_plane = torch.where(
                theta_distorted[..., None] > 0,
                distorted / theta_distorted.clamp_min(1e-300)[..., None],
                torch.zeros_like(distorted),
            )
            return torch.cat([in_plane * torch.sin(theta)[..., None], torch.cos(theta)[..., None]], dim=-1)
        undistorted = undistort_opencv(distorted, coefficients) if self.model == "OPENCV" else distorted
        directions = torch.cat([undistorted, torch.ones_like(undistorted[..., :1])], dim=-1)
        return torch.nn.functional.normalize(directions, dim=-1)


def _per_camera(value, count: int, name: str, kind: dict) -> torch.Tensor:
    tensor = torch.as_tensor(value, **kind).reshape(-1)
    if len(tensor) not in (1, count):
        raise ValueError(f"{name} must be a scalar or have one value per camera ({count}), got {len(tensor)}")
    return tensor.expand(count).contiguous()


def distort_opencv(normalized: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """Apply OpenCV radial-tangential distortion to normalised coordinates ``S + (2,)``.

    ``coefficients`` ``S + (5,)`` are (k1, k2, p1, p2, k3); the formula is in the module docstring.
    """
    x, y = normalized[..., 0], normalized[..., 1]
    k1, k2, p1, p2, k3 = coefficients.unbind(-1)
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    x_d = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    y_d = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return torch.stack([x_d, y_d], dim=-1)


def undistort_opencv(distorted: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """Invert :func:`distort_opencv` by Newton's method on the 2x2 system, ``S + (2,)``.

    Starts from the distorted point and runs at most :data:`UNDISTORT_ITERATIONS` steps with the
    analytic Jacobian, stopping early once every step is below 1e-12.
    """
    k1, k2, p1, p2, k3 = coefficients.unbind(-1)
    x_d, y_d = distorted[..., 0], distorted[..., 1]
    x, y = x_d.clone(), y_d.clone()
    for _ in range(UNDISTORT_ITERATIONS):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        # d(radial)/d(r^2); d(r^2)/dx = 2x.
        radial_slope = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        residual_x = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - x_d
        residual_y = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - y_d
        dxd_dx = radial + 2 * x * x * radial_slope + 2 * p1 * y + 6 * p2 * x
        dxd_dy = 2 * x * y * radial_slope + 2 * p1 * x + 2 * p2 * y
        dyd_dx = 2 * x * y * radial_slope + 2 * p1 * x + 2 * p2 * y
        dyd_dy = radial + 2 * y * y * radial_slope + 6 * p1 * y + 2 * p2 * x
        determinant = dxd_dx * dyd_dy - dxd_dy * dyd_dx
        determinant = torch.where(determinant.abs() > 1e-12, determinant, torch.full_like(determinant, 1e-12))
        step_x = (residual_x * dyd_dy - residual_y * dxd_dy) / determinant
        step_y = (residual_y * dxd_dx - residual_x * dyd_dx) / determinant
        x, y = x - step_x, y - step_y
        if _converged(step_x, step_y):
            break
    return torch.stack([x, y], dim=-1)


def _fisheye_polynomial(theta: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    k1, k2, k3, k4 = coefficients.unbind(-1)
    t2 = theta * theta
    return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def undistort_fisheye_angle(theta_distorted: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """Solve ``theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) = theta_d`` for theta in [0, pi] by Newton's method."""
    k1, k2, k3, k4 = coefficients.unbind(-1)
    theta = theta_distorted.clamp(0, torch.pi)
    for _ in range(UNDISTORT_ITERATIONS):
        t2 = theta * theta
        value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_distorted
        slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        slope = torch.where(slope.abs() > 1e-12, slope, torch.full_like(slope, 1e-12))
        step = value / slope
        theta = (theta - step).clamp(0, torch.pi)
        if _converged(step):
            break
    return theta


def _converged(*steps: torch.Tensor) -> bool:
    """True once every Newton step is below 1e-12 (radians or normalised units), NaNs aside."""
    return all(step.numel() == 0 or bool((step.abs().nan_to_num(0) < 1e-12).all()) for step in steps)
