"""Empty-space skipping (issue 6): ray-box intersection, the occupancy grid and the marcher."""

import math

import pytest
import torch

from pointfield.compiling import compiler_available
from pointfield.fields.encodings.contraction import box_to_unit
from pointfield.fields.rays import RayBundle
from pointfield.fields.sampling.occupancy import OccupancyGrid, march_rays, ray_box_intersection

UNIT_BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


# -- boxes and marching --------------------------------------------------------------------------------


def test_ray_box_intersection_of_a_hit_a_miss_and_a_ray_starting_inside():
    origins = torch.tensor([[-3.0, 0.0, 0.0], [-3.0, 2.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 3.0], [-3.0, -3.0, -3.0]])
    directions = torch.nn.functional.normalize(
        torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 1.0, 1.0]]), dim=-1
    )
    enter, leave = ray_box_intersection(origins, directions, UNIT_BOX)
    root3 = math.sqrt(3)
    hits = [0, 2, 3, 4]
    torch.testing.assert_close(enter[hits], torch.tensor([2.0, -1.0, 2.0, 2 * root3]))
    torch.testing.assert_close(leave[hits], torch.tensor([4.0, 1.0, 4.0, 4 * root3]))
    assert enter[1] >= leave[1]  # passes above the box


def _sphere_grid(resolution=8, radius=0.6):
    """An occupancy grid over the unit box whose occupied cells are those with centres in a ball."""
    grid = OccupancyGrid(UNIT_BOX, resolution)
    axis = (torch.arange(resolution) + 0.5) / resolution * 2 - 1
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")  # the grid's flat order: x major
    grid.occupied.copy_(((x**2 + y**2 + z**2) < radius**2).reshape(-1))
    return grid


@pytest.mark.parametrize("backend", ["eager", "compiled"])
def test_marching_keeps_exactly_the_steps_in_occupied_cells_within_near_far_and_the_box(backend, rays_at_the_box):
    if backend == "compiled" and not compiler_available(torch.device("cpu")):
        pytest.skip("no C++ compiler here for torch.compile")
    grid = _sphere_grid()
    origins, directions, near, far = rays_at_the_box(40)
    step = 0.05
    samples = march_rays(RayBundle(origins, directions, near, far), grid, step, backend=backend)
    enter, leave = ray_box_intersection(origins, directions, grid.box)
    start, stop = torch.maximum(enter, near), torch.minimum(leave, far)
    for ray in range(len(origins)):
        mine = samples.ray_indices == ray
        # Step by step, as the docstring says: [start + k step, min(start + (k + 1) step, stop)).
        expected = []
        k = 0
        while float(start[ray]) + k * step < float(stop[ray]):
            t0 = start[ray] + k * step
            t1 = torch.minimum(t0 + step, stop[ray])
            if grid.occupied_at(origins[ray] + 0.5 * (t0 + t1) * directions[ray]):
                expected.append((float(t0), float(t1)))
            k += 1
        got = list(zip(samples.t_starts[mine].tolist(), samples.t_ends[mine].tolist()))
        assert len(got) == len(expected), f"ray {ray}"
        if expected:
            torch.testing.assert_close(torch.tensor(got), torch.tensor(expected), atol=1e-5, rtol=0)
    assert 0 < len(samples) < sum(math.ceil(max(float(s), 0) / step) for s in (stop - start))


def test_marched_samples_are_packed_in_increasing_t_inside_the_bounds(rays_at_the_box):
    grid = _sphere_grid()
    origins, directions, near, far = rays_at_the_box(64, seed=1)
    rays = RayBundle(origins, directions, near, far)
    samples = march_rays(rays, grid, 0.03, jitter=True, generator=torch.Generator().manual_seed(2))
    indices = samples.ray_indices
    assert samples.is_packed and samples.num_rays == 64
    assert len(samples) > 0 and bool((indices[1:] >= indices[:-1]).all())
    same_ray = indices[1:] == indices[:-1]
    assert bool((samples.t_starts[1:][same_ray] >= samples.t_ends[:-1][same_ray] - 1e-6).all())
    assert bool((samples.t_ends > samples.t_starts).all())
    assert bool((samples.t_ends - samples.t_starts <= 0.03 + 1e-6).all())
    assert bool((samples.t_starts >= near[indices] - 1e-6).all() and (samples.t_ends <= far[indices] + 1e-6).all())
    assert bool(grid.occupied_at(samples.positions(rays)).all())
    unit = box_to_unit(samples.positions(rays), grid.box)
    assert bool(((unit >= 0) & (unit <= 1)).all())


def test_rays_that_miss_the_box_or_see_only_empty_cells_get_no_samples():
    grid = _sphere_grid()
    origins = torch.tensor([[-3.0, 2.0, 0.0], [-3.0, 0.9, 0.9]])  # misses; crosses only corner cells
    directions = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    samples = march_rays(RayBundle(origins, directions, torch.full((2,), 0.5), torch.full((2,), 6.0)), grid, 0.05)
    assert len(samples) == 0 and samples.num_rays == 2


# -- the occupancy grid --------------------------------------------------------------------------------


def _dense_ball(positions):
    """Density 1000 inside the ball of radius 0.5 about the origin, 0 outside."""
    return torch.where(positions.norm(dim=-1) < 0.5, 1000.0, 0.0)


def _cell_bounds(resolution):
    """Each cell's min and max corner ``(cells, 3)`` over the unit box, in the grid's flat (x-major) order."""
    index = torch.arange(resolution**3)
    cell = torch.stack([index // resolution**2, (index // resolution) % resolution, index % resolution], dim=-1)
    return cell / resolution * 2 - 1, (cell + 1) / resolution * 2 - 1


def test_occupancy_grid_marks_a_dense_ball_occupied_and_the_far_corners_empty_after_warm_up():
    resolution = 16
    grid = OccupancyGrid(UNIT_BOX, resolution, update_every=2, warmup_steps=6)
    assert grid.occupancy == 1.0  # nothing is known to be empty yet
    generator = torch.Generator().manual_seed(0)
    updated = [grid.update(_dense_ball, step, step_size=0.01, generator=generator) for step in range(12)]
    assert updated == [step % 2 == 0 for step in range(12)]
    lower, upper = _cell_bounds(resolution)
    farthest = torch.maximum(lower.abs(), upper.abs()).norm(dim=-1)  # cell point farthest from the origin
    closest = torch.clamp(torch.zeros(3), lower, upper).norm(dim=-1)  # and the closest
    inside_ball, away_from_ball = farthest < 0.5, closest > 0.5
    assert int(inside_ball.sum()) > 0 and int(away_from_ball.sum()) > 0
    assert bool(grid.occupied[inside_ball].all())
    assert not bool(grid.occupied[away_from_ball].any())
    far_corners = torch.tensor([[-0.95, -0.95, -0.95], [0.95, 0.95, 0.95], [0.95, -0.95, 0.95]])
    assert not bool(grid.occupied_at(far_corners).any())
    assert bool(grid.occupied_at(torch.zeros(1, 3)).all())


def test_after_warm_up_only_a_fraction_of_the_cells_is_refreshed():
    grid = OccupancyGrid(UNIT_BOX, 16, decay=0.5, update_every=1, warmup_steps=1, update_fraction=0.25)
    generator = torch.Generator().manual_seed(0)
    grid.update(_dense_ball, 0, step_size=0.01, generator=generator)  # the warm-up step: every cell
    before = grid.density.clone()
    grid.update(lambda positions: torch.zeros(len(positions)), 1, step_size=0.01, generator=generator)
    changed = grid.density != before
    assert 0 < int(changed.sum()) <= 0.25 * 16**3
    refreshed_ball = changed & (before > 0)
    # Refreshed with density 0: the moving maximum decays.
    torch.testing.assert_close(grid.density[refreshed_ball], before[refreshed_ball] * 0.5)
