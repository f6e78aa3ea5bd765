"""Every ray is marched where the scene is, whichever camera it comes from (``SceneExtent``).

A field's rays used to run between the training cameras' nearest and farthest depth bounds,
so a camera nearer than those saw the object cut open, or nothing. Now each ray runs from where
it enters the scene box to where it leaves it (from a small near plane when the camera is
inside), and a ray that misses the box renders the background. Checked with an oracle field
that is the synthetic cube itself (opaque inside it, nothing outside), against the analytic
silhouette of the same cameras (``render_scene``'s alpha).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pointfield.fields.field import FieldOutput, RadianceField
from pointfield.fields.nerf import TinyNeRF
from pointfield.fields.rays import NEAR_PLANE, RayBundle, RaySamples, SceneExtent
from pointfield.fields.rendering import render_rays
from pointfield.fields.run import render_field
from pointfield.fields.sampling import stratified_samples
from pointfield.scenes.cameras import Cameras, look_at
from pointfield.scenes.synthetic import padded_aabb, render_scene, synthetic_cameras

CUBE_BOX = SceneExtent(padded_aabb(((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))).tolist())
TRAINING_DISTANCE = 4.0


class OracleCube(RadianceField):
    """The synthetic cube as a field: density 1e3 inside ``|x| <= 0.5``, 0 outside, white; 512 samples a ray."""

    def field(self, positions, directions):
        inside = (positions.abs() <= 0.5).all(dim=-1)
        return torch.where(inside, 1e3, 0.0), torch.ones_like(positions)

    def forward(self, rays, background=None, jitter=False, generator=None) -> FieldOutput:
        t = stratified_samples(rays.near, rays.far, 512, jitter=False)
        samples = RaySamples.from_points(t, rays.far)
        return FieldOutput([render_rays(self.field, rays, samples, background)], samples=len(samples))


def silhouette_error(cameras: Cameras) -> float:
    """Mean |rendered opacity - analytic alpha| over the oracle's render of every camera."""
    _, _, mask = render_scene("cube", cameras, supersampling=1)  # the pixel-centre ray, as renders use
    errors = []
    for index in range(len(cameras)):
        view = render_field(OracleCube(), cameras, index, CUBE_BOX, torch.zeros(3))
        errors.append(float(np.abs(view["opacity"].numpy() - mask[index]).mean()))
    return float(np.mean(errors))


def test_near_far_is_where_each_ray_enters_and_leaves_the_box():
    extent = SceneExtent(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)))
    origins = torch.tensor([[0.0, 0.0, -3.0], [-3.0, 0.5, 0.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    near, far = extent.near_far(origins, directions)
    assert near.tolist() == pytest.approx([2.0, 2.0]) and far.tolist() == pytest.approx([4.0, 4.0])


def test_a_camera_inside_the_box_starts_its_rays_at_the_near_plane():
    extent = SceneExtent(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)))
    near, far = extent.near_far(torch.zeros(1, 3), torch.tensor([[0.0, 1.0, 0.0]]))
    assert float(near) == pytest.approx(NEAR_PLANE * extent.diagonal) and float(far) == pytest.approx(1.0)


def test_an_unbounded_scene_runs_its_rays_from_the_near_plane_to_the_end_of_contracted_space():
    extent = SceneExtent(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)), unbounded=True)
    near, far = extent.near_far(torch.tensor([[0.0, 0.0, -30.0]]), torch.tensor([[0.0, 0.0, 1.0]]))
    assert float(near) == pytest.approx(extent.near_plane) and float(far) > 1000 * extent.diagonal / 2 - 1


def test_rays_that_miss_the_box_render_the_background():
    extent = SceneExtent(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)))
    origins = torch.tensor([[0.0, 3.0, -3.0]]).expand(4, 3)
    rays = RayBundle.within(origins, torch.tensor([[0.0, 0.0, 1.0]]).expand(4, 3), extent)
    background = torch.tensor([0.2, 0.4, 0.6])
    torch.manual_seed(0)
    with torch.no_grad():
        rendered = TinyNeRF(samples=16)(rays, background).final  # an untrained field is dense everywhere
    assert torch.allclose(rendered.color, background.expand(4, 3)) and float(rendered.opacity.abs().max()) == 0


@pytest.mark.parametrize("factor", [0.65, 1.0, 1.3])
def test_cameras_nearer_and_farther_than_the_training_ones_see_the_whole_cube(factor):
    cameras = synthetic_cameras(4, 32, radius=factor * TRAINING_DISTANCE).to(dtype=torch.float32)
    # Pixels the silhouette's edge crosses differ by one pixel at most: about 3 % of a 32 x 32 view.
    assert silhouette_error(cameras) < 0.04


def test_a_camera_inside_the_box_sees_the_face_in_front_of_it():
    # Inside the padded box, 0.05 above the cube's top face, looking straight down at it.
    pose = look_at(np.array([[0.0, 0.0, 0.55]]), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    camera = Cameras(pose, 16.0, 16.0, 16.0, 16.0, 32, 32).to(dtype=torch.float32)
    view = render_field(OracleCube(), camera, 0, CUBE_BOX, torch.zeros(3))
    assert float(view["opacity"].min()) > 0.99
    assert float(view["depth"][16, 16]) == pytest.approx(0.05, abs=0.01)
