"""The tile rasterizer agrees with the dense reference in images and gradients, and gradchecks.

Both of its compositing paths are held to the reference: the differentiable one (inputs that
require gradients) and the in-place one used whenever no gradient can flow.
"""

import contextlib
import math
import warnings

import pytest
import torch

from pointfield.compiling import compiler_available
from pointfield.splats.ply import read_splats
from pointfield.splats.rasterizer import (
    MIN_ALPHA,
    SCREEN_DILATION,
    SIGMA_EXTENT,
    project_gaussians,
    rasterization,
    tile_intersections,
)
from pointfield.splats.reference import rasterization_reference

PATHS = ["differentiable", "no_grad", "no_grad_eager"]
"""Compositing paths: with gradients; without, compiled where a compiler exists; without, eagerly."""


def tiny_scene(count: int, seed: int, spread: float = 0.6):
    """``count`` random splats about 4 units in front of an identity camera, float64."""
    generator = torch.Generator().manual_seed(seed)
    dt = torch.float64
    means = torch.randn(count, 3, generator=generator, dtype=dt) * spread + torch.tensor([0, 0, 4.0], dtype=dt)
    quats = torch.randn(count, 4, generator=generator, dtype=dt)
    scales = torch.rand(count, 3, generator=generator, dtype=dt) * 0.2 + 0.03
    opacities = torch.rand(count, generator=generator, dtype=dt) * 0.9 + 0.05
    colors = torch.rand(count, 3, generator=generator, dtype=dt)
    return [means, quats, scales, opacities, colors]


def cameras(count: int = 2):
    dt = torch.float64
    Ks = torch.tensor([[40.0, 0, 20], [0, 42.0, 17], [0, 0, 1]], dtype=dt).repeat(count, 1, 1)
    viewmats = torch.eye(4, dtype=dt).repeat(count, 1, 1)
    if count > 1:
        # The second camera: 20 degrees about y and shifted, still facing the splats.
        angle = math.radians(20)
        viewmats[1, :3, :3] = torch.tensor([[math.cos(angle), 0, -math.sin(angle)], [0, 1, 0],
                                            [math.sin(angle), 0, math.cos(angle)]], dtype=dt)
        viewmats[1, :3, 3] = torch.tensor([1.2, 0.1, 0.3], dtype=dt)
    return viewmats, Ks


def render(path: str, splats, *args, **kwargs):
    """``rasterization`` through one compositing path: inputs requiring gradients, or none."""
    if path == "differentiable":
        splats = [tensor.detach().requires_grad_() for tensor in splats]
    if path == "no_grad_eager":
        kwargs["backend"] = "eager"
    with torch.no_grad() if path.startswith("no_grad") else contextlib.nullcontext():
        return rasterization(*splats, *args, **kwargs)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("seed", [0, 1])
def test_images_match_the_reference(seed, path):
    splats = tiny_scene(30, seed)
    viewmats, Ks = cameras()
    background = torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64)
    fast = render(path, splats, viewmats, Ks, 40, 35, backgrounds=background)
    slow = rasterization_reference(*splats, viewmats, Ks, 40, 35, backgrounds=background)
    for name, a, b in zip(("colors", "depths", "alphas"), fast[:3], slow):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0, msg=name)
    assert fast[2].max() > 0.5, "the scene should cover part of the image"


def test_gradients_match_the_reference():
    splats = [tensor.requires_grad_() for tensor in tiny_scene(25, 3)]
    viewmats, Ks = cameras()
    fast = rasterization(*splats, viewmats, Ks, 40, 35)
    slow = rasterization_reference(*splats, viewmats, Ks, 40, 35)
    weights = torch.randn_like(fast[0])

    def objective(colors, depths, alphas):
        return (colors * weights).sum() + 0.1 * depths.sum() + alphas.sum()

    fast_grads = torch.autograd.grad(objective(*fast[:3]), splats)
    slow_grads = torch.autograd.grad(objective(*slow), splats)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), fast_grads, slow_grads):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-9, msg=name)


@pytest.mark.parametrize("path", PATHS)
def test_spherical_harmonic_colours_match_the_reference(path):
    means, quats, scales, opacities, _ = tiny_scene(12, 5)
    coefficients = torch.randn(12, 16, 3, dtype=torch.float64) * 0.3
    viewmats, Ks = cameras()
    fast = render(path, [means, quats, scales, opacities, coefficients], viewmats, Ks, 40, 35, sh_degree=3)
    slow = rasterization_reference(means, quats, scales, opacities, coefficients, viewmats, Ks, 40, 35, sh_degree=3)
    torch.testing.assert_close(fast[0], slow[0], atol=1e-12, rtol=0)


def test_gradcheck_on_a_tiny_scene():
    splats = [tensor.requires_grad_() for tensor in tiny_scene(4, 1, spread=0.4)]
    splats[2].data = splats[2].data + 0.08
    viewmats, Ks = cameras(1)
    Ks = Ks / 2
    Ks[:, 2, 2] = 1

    def render(*inputs):
        return rasterization(*inputs, viewmats, Ks, 20, 18)[:3]

    assert torch.autograd.gradcheck(render, splats, eps=1e-6, atol=1e-5, fast_mode=True)


@pytest.mark.parametrize("path", PATHS)
def test_saturated_pixels_stop_and_alpha_never_exceeds_one(path):
    # Twenty opaque splats stacked on the optical axis: the pixel stops before T < 1e-4.
    count = 20
    dt = torch.float64
    means = torch.zeros(count, 3, dtype=dt)
    means[:, 2] = torch.linspace(2, 6, count, dtype=dt)
    splats = [means, torch.tensor([[1.0, 0, 0, 0]], dtype=dt).repeat(count, 1),
              torch.full((count, 3), 0.5, dtype=dt), torch.full((count,), 0.999, dtype=dt),
              torch.eye(count, dtype=dt)]
    viewmats, Ks = cameras(1)
    colors, _, alphas, _ = render(path, splats, viewmats, Ks, 40, 35, splats_per_slice=1)
    centre = colors[0, 17, 20].detach()
    # alpha clamps at 0.99: T after k splats is 0.01^k, so only the first two splats count.
    torch.testing.assert_close(centre[:3], torch.tensor([0.99, 0.0099, 0], dtype=dt))
    assert centre[2:].abs().max() == 0
    assert alphas.max() <= 1


@pytest.mark.parametrize("path", PATHS)
def test_splats_behind_the_camera_are_not_drawn(path):
    splats = tiny_scene(5, 0)
    splats[0] = splats[0] * torch.tensor([1, 1, -1.0], dtype=torch.float64)
    viewmats, Ks = cameras(1)
    colors, depths, alphas, meta = render(path, splats, viewmats, Ks, 40, 35)
    assert alphas.max() == 0
    assert (meta["radii"] == 0).all()


def test_the_result_does_not_depend_on_the_batching_of_tiles_or_splats():
    splats = [tensor.requires_grad_() for tensor in tiny_scene(40, 7)]
    viewmats, Ks = cameras(1)
    whole = rasterization(*splats, viewmats, Ks, 40, 35)
    piecewise = rasterization(*splats, viewmats, Ks, 40, 35, max_block_elements=1, splats_per_slice=3)
    with torch.no_grad():
        piecewise_no_grad = rasterization(*splats, viewmats, Ks, 40, 35, max_block_elements=1, splats_per_slice=3)
    for a, b, c in zip(whole[:3], piecewise[:3], piecewise_no_grad[:3]):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)
        torch.testing.assert_close(a.detach(), c, atol=1e-12, rtol=0)
    weights = torch.randn_like(whole[0])
    for a, b in zip(torch.autograd.grad((whole[0] * weights).sum() + whole[1].sum(), splats),
                    torch.autograd.grad((piecewise[0] * weights).sum() + piecewise[1].sum(), splats)):
        torch.testing.assert_close(a, b, atol=1e-10, rtol=1e-10)


def test_screen_space_gradients_reach_means2d():
    splats = [tensor.requires_grad_() for tensor in tiny_scene(10, 2)]
    viewmats, Ks = cameras(1)
    colors, _, _, meta = rasterization(*splats, viewmats, Ks, 40, 35)
    meta["means2d"].retain_grad()
    colors.sum().backward()
    assert meta["means2d"].grad.shape == (1, 10, 2)
    assert meta["means2d"].grad[meta["radii"] > 0].abs().sum() > 0


def test_the_real_3dgs_file_renders(shared_data):
    gaussians = read_splats(shared_data / "gaussians/3dgs_point_cloud_iter7000.ply")
    width, height = 40, 32
    K = torch.tensor([[[30.0, 0, width / 2], [0, 30.0, height / 2], [0, 0, 1]]])
    with torch.no_grad():
        colors, _, alphas, meta = rasterization(
            gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
            gaussians.sh_coefficients, torch.eye(4)[None], K, width, height, sh_degree=3,
        )
    assert (meta["radii"] > 0).sum() > 1000
    assert alphas.mean() > 0.5, "the camera at the origin looks into the captured room"
    assert torch.isfinite(colors).all() and colors.std() > 0.01


@pytest.mark.parametrize("tile_size", [1, 3, 4, 16])
@pytest.mark.parametrize("path", PATHS)
def test_the_image_does_not_depend_on_the_tile_size(tile_size, path):
    splats = tiny_scene(30, 11)
    viewmats, Ks = cameras()
    background = torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64)
    tiled = render(path, splats, viewmats, Ks, 40, 35, backgrounds=background, tile_size=tile_size)
    slow = rasterization_reference(*splats, viewmats, Ks, 40, 35, backgrounds=background)
    for name, a, b in zip(("colors", "depths", "alphas"), tiled[:3], slow):
        torch.testing.assert_close(a.detach(), b, atol=1e-12, rtol=0, msg=name)


def test_rendering_without_gradients_matches_the_differentiable_path():
    # Many overlapping splats (pixels saturate and stop), SH colours, a background and more
    # splats per tile than one slice holds.
    means, quats, scales, opacities, _ = tiny_scene(300, 12, spread=0.5)
    opacities = opacities.clamp(0.3, 0.99)
    coefficients = torch.randn(300, 16, 3, dtype=torch.float64) * 0.3
    splats = [means, quats, scales, opacities, coefficients]
    viewmats, Ks = cameras()
    background = torch.tensor([1.0, 1.0, 1.0], dtype=torch.float64)
    kwargs = dict(sh_degree=3, backgrounds=background, splats_per_slice=16)
    with_grad = render("differentiable", splats, viewmats, Ks, 40, 35, **kwargs)
    without = render("no_grad", splats, viewmats, Ks, 40, 35, **kwargs)
    assert (with_grad[2] > 0.999).float().mean() > 0.05, "some pixels should be saturated"
    for name, a, b in zip(("colors", "depths", "alphas"), with_grad[:3], without[:3]):
        torch.testing.assert_close(a.detach(), b, atol=1e-12, rtol=0, msg=name)
    for key in ("means2d", "radii", "depths"):
        torch.testing.assert_close(with_grad[3][key].detach(), without[3][key])


def test_transparent_splats_are_culled_and_change_nothing():
    splats = tiny_scene(20, 4)
    splats[3][::2] = 0.5 * MIN_ALPHA  # too faint for any pixel
    viewmats, Ks = cameras(1)
    projection = project_gaussians(*splats[:3], viewmats[0], Ks[0], 40, 35)
    splat_ids, _ = tile_intersections(
        projection.means2d, projection.conics, splats[3], projection.depths, projection.visible, 40, 35,
    )
    assert len(splat_ids) > 0 and (splat_ids % 2 == 1).all()
    for path in PATHS:
        fast = render(path, splats, viewmats, Ks, 40, 35)
        slow = rasterization_reference(*splats, viewmats, Ks, 40, 35)
        for a, b in zip(fast[:3], slow):
            torch.testing.assert_close(a.detach(), b, atol=1e-12, rtol=0)


def needles_and_blobs(seed: int):
    """Long thin rotated splats, round ones and faint ones, some over the image border, float64."""
    generator = torch.Generator().manual_seed(seed)
    dt = torch.float64
    count = 60
    means = torch.rand(count, 3, generator=generator, dtype=dt) * torch.tensor([3.0, 3.0, 2.0], dtype=dt) \
        + torch.tensor([-1.5, -1.5, 3.0], dtype=dt)
    quats = torch.randn(count, 4, generator=generator, dtype=dt)
    scales = torch.rand(count, 3, generator=generator, dtype=dt) * 0.1 + 0.01
    scales[::3, 0] = 1.0  # needles, up to ~40 pixels long and a pixel wide
    opacities = torch.rand(count, generator=generator, dtype=dt)
    opacities[::4] = torch.rand(count // 4, generator=generator, dtype=dt) * 0.02  # reach < 3 sigma
    return means, quats, scales, opacities


@pytest.mark.parametrize("backend", ["eager", "compiled"])
@pytest.mark.parametrize("tile_size", [1, 3, 4, 16])
def test_tile_binning_finds_every_pixel_a_splat_reaches(tile_size, backend):
    if backend == "compiled" and not compiler_available(torch.device("cpu")):
        pytest.skip("no C++ compiler here for torch.compile")
    means, quats, scales, opacities = needles_and_blobs(tile_size)
    viewmats, Ks = cameras(1)
    width, height = 41, 35  # neither a multiple of the tile size
    projection = project_gaussians(means, quats, scales, viewmats[0], Ks[0], width, height)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message="torch.compile of")  # no silent fallback to eager
        splat_ids, tile_ids = tile_intersections(
            projection.means2d, projection.conics, opacities, projection.depths, projection.visible,
            width, height, tile_size, backend,
        )
    # Every (pixel, splat) that step 5 keeps, found by testing every pixel.
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64) + 0.5,
                          torch.arange(width, dtype=torch.float64) + 0.5, indexing="ij")
    a, b, c = projection.conics.unbind(-1)
    dx = u.flatten()[:, None] - projection.means2d[:, 0]
    dy = v.flatten()[:, None] - projection.means2d[:, 1]
    sigma = 0.5 * a * dx * dx + b * dx * dy + 0.5 * c * dy * dy                     # (pixels, N)
    kept = (sigma <= 0.5 * SIGMA_EXTENT**2) & (opacities * torch.exp(-sigma) >= MIN_ALPHA) & projection.visible
    pixel, splat = torch.nonzero(kept, as_tuple=True)
    tiles_x = math.ceil(width / tile_size)
    needed = set(zip(splat.tolist(), ((pixel // width // tile_size) * tiles_x + pixel % width // tile_size).tolist()))
    found = set(zip(splat_ids.tolist(), tile_ids.tolist()))
    assert len(needed) > 100
    assert needed <= found
    # And the bound is close: few pairs reach no pixel at all.
    assert len(found - needed) <= 0.2 * len(found)
    # Sorted by tile, then front to back within each tile.
    assert (tile_ids[1:] >= tile_ids[:-1]).all()
    same_tile = tile_ids[1:] == tile_ids[:-1]
    assert (projection.depths[splat_ids[1:]][same_tile] >= projection.depths[splat_ids[:-1]][same_tile]).all()


def test_both_paths_render_the_real_3dgs_file_alike_in_float32(shared_data):
    gaussians = read_splats(shared_data / "gaussians/3dgs_point_cloud_iter7000.ply")
    K = torch.tensor([[[30.0, 0, 20.0], [0, 30.0, 16.0], [0, 0, 1]]])
    splats = [gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh_coefficients]
    with_grad = render("differentiable", splats, torch.eye(4)[None], K, 40, 32, sh_degree=3)
    without = render("no_grad", splats, torch.eye(4)[None], K, 40, 32, sh_degree=3)
    assert without[0].dtype == torch.float32
    torch.testing.assert_close(without[0], with_grad[0].detach(), atol=1e-5, rtol=0)
    torch.testing.assert_close(without[2], with_grad[2].detach(), atol=1e-5, rtol=0)
    torch.testing.assert_close(without[1], with_grad[1].detach(), atol=1e-3, rtol=1e-5)  # depths ~ 300


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize(("antialiased", "dilation"), [(False, SCREEN_DILATION), (True, 0.1)])
def test_cuda_renders_and_differentiates_like_the_cpu(antialiased, dilation):
    splats = [tensor.float() for tensor in tiny_scene(200, 21)]
    viewmats, Ks = (tensor.float() for tensor in cameras())
    results = {}
    for device in ("cpu", "cuda"):
        # a copy per device: on the CPU .to() returns the tensor itself, whose requires_grad
        # would make the CUDA copies non-leaf tensors, without .grad
        inputs = [tensor.detach().clone().to(device).requires_grad_() for tensor in splats]
        colors, depths, alphas, _ = rasterization(*inputs, viewmats.to(device), Ks.to(device), 40, 35,
                                                  antialiased=antialiased, screen_dilation=dilation)
        (colors.sum() + alphas.sum()).backward()
        results[device] = [colors.detach().cpu(), depths.detach().cpu(), alphas.detach().cpu(),
                           *(tensor.grad.cpu() for tensor in inputs)]
    for on_cpu, on_cuda in zip(results["cpu"], results["cuda"]):
        torch.testing.assert_close(on_cuda, on_cpu, atol=1e-4, rtol=1e-3)


def test_rendering_a_model_whose_splat_count_changes_compiles_the_projection_once():
    # Densification changes the count every few hundred steps, and evaluation renders the model's
    # nn.Parameters: compiled per count, the projection would fall back to eager after
    # RECOMPILE_LIMIT counts (and pay a compile at each one before that).
    if not compiler_available(torch.device("cpu")):
        pytest.skip("no C++ compiler here for torch.compile")
    from torch._dynamo.utils import counters

    viewmats, Ks = cameras(1)
    graphs = []
    for count in (30, 35, 41, 47, 55):
        means, quats, scales, opacities = (torch.nn.Parameter(t[:count]) for t in needles_and_blobs(4))
        with torch.no_grad():
            rasterization(means, quats, scales, opacities, torch.rand(count, 3, dtype=means.dtype), viewmats, Ks,
                          32, 32, backend="compiled")
        graphs.append(counters["stats"]["unique_graphs"])
    # Counted from after the first count's render: the later counts reuse its graph (one more
    # compile allowed, for dynamo turning a shape it first saw static into a dynamic one).
    assert graphs[-1] - graphs[0] <= 1


@pytest.mark.parametrize(("antialiased", "dilation"), [(True, SCREEN_DILATION), (True, 0.1), (False, 0.1)])
@pytest.mark.parametrize("path", PATHS)
def test_images_match_the_reference_in_each_rasterizer_mode(path, antialiased, dilation):
    # (Classic at the default dilation: test_images_match_the_reference.)
    splats = tiny_scene(30, 2)
    viewmats, Ks = cameras()
    fast = render(path, splats, viewmats, Ks, 40, 35, antialiased=antialiased, screen_dilation=dilation)
    slow = rasterization_reference(*splats, viewmats, Ks, 40, 35, antialiased=antialiased, screen_dilation=dilation)
    for name, a, b in zip(("colors", "depths", "alphas"), fast[:3], slow):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0, msg=name)
    # Each setting reaches the arithmetic (matching a reference that ignored it too would not show it).
    if antialiased:
        classic = render(path, splats, viewmats, Ks, 40, 35, screen_dilation=dilation)
        assert float(fast[2].detach().sum()) < float(classic[2].detach().sum()), "the compensation only lowers opacity"
    if dilation != SCREEN_DILATION:
        default = render(path, splats, viewmats, Ks, 40, 35, antialiased=antialiased)
        assert float((fast[2] - default[2]).detach().abs().max()) > 1e-3, "the dilation should change the image"


@pytest.mark.parametrize("dilation", [SCREEN_DILATION, 0.1])
def test_antialiased_gradients_match_the_reference_and_stay_finite_edge_on(dilation):
    splats = [tensor.requires_grad_() for tensor in tiny_scene(25, 4)]
    viewmats, Ks = cameras()
    mode = {"antialiased": True, "screen_dilation": dilation}
    fast = rasterization(*splats, viewmats, Ks, 40, 35, **mode)
    slow = rasterization_reference(*splats, viewmats, Ks, 40, 35, **mode)
    fast_grads = torch.autograd.grad(fast[0].sum() + fast[2].sum(), splats)
    slow_grads = torch.autograd.grad(slow[0].sum() + slow[2].sum(), splats)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), fast_grads, slow_grads):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-9, msg=name)
    # A flat disc seen exactly edge on has no area on screen: its undilated determinant is 0
    # (or, rounded, a hair below), where the square root's gradient is infinite.
    means = torch.tensor([[0.0, 0.0, 4.0]], dtype=torch.float64, requires_grad=True)
    quats = torch.tensor([[0.5 ** 0.5, 0.5 ** 0.5, 0.0, 0.0]], dtype=torch.float64)  # disc normal along -y
    scales = torch.tensor([[0.3, 0.0, 0.3]], dtype=torch.float64, requires_grad=True)
    edge_on = rasterization(means, quats, scales, torch.tensor([0.9], dtype=torch.float64),
                            torch.ones(1, 3, dtype=torch.float64), viewmats[:1], Ks[:1], 40, 35, **mode)
    gradients = torch.autograd.grad(edge_on[2].sum(), (means, scales), allow_unused=True)
    assert all(g is None or bool(torch.isfinite(g).all()) for g in gradients)


def test_antialiased_mode_keeps_a_surface_of_small_splats_inside_its_outline():
    # A 20 x 21 pixel square at z = 4 tiled with 10,000 opaque discs a tenth of a pixel wide:
    # classic 3DGS draws each as a dilated blob about a pixel wide, so the square's outline
    # swells; antialiased, each disc's opacity shrinks with its dilation and the outline stays.
    # A smaller dilation (Mip-Splatting's 0.1 px^2 against 3DGS's 0.3) swells classic less.
    dt = torch.float64
    side = torch.linspace(-1, 1, 100, dtype=dt)
    y, x = torch.meshgrid(side, side, indexing="ij")
    means = torch.stack([x.flatten() - 0.25, y.flatten() - 0.125, torch.full((10_000,), 4.0, dtype=dt)], dim=-1)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=dt).repeat(10_000, 1)
    scales = torch.tensor([[0.01, 0.01, 1e-6]], dtype=dt).repeat(10_000, 1)
    opacities = torch.full((10_000,), 0.99, dtype=dt)
    colors = torch.ones(10_000, 3, dtype=dt)
    viewmats, Ks = cameras(1)
    square = 20 * 21  # pixels: 2 units at z = 4, focal lengths 40 and 42
    with torch.no_grad():
        areas = {(mode, dilation): float((rasterization(means, quats, scales, opacities, colors, viewmats, Ks, 40, 35,
                                                        antialiased=mode, screen_dilation=dilation)[2] > 0.5).sum())
                 for mode in (False, True) for dilation in (SCREEN_DILATION, 0.1)}
    assert areas[False, SCREEN_DILATION] > 1.15 * square, areas   # 527 pixels
    assert areas[False, 0.1] < areas[False, SCREEN_DILATION] - 0.1 * square, areas   # 462
    assert areas[True, SCREEN_DILATION] < 1.08 * square, areas   # 439
    assert areas[True, 0.1] < 1.08 * square, areas   # 441
