"""The optional gsplat rasterizer: chosen only where it can run, and rendering what pointfield renders."""

import pytest
import torch

from pointfield.errors import PointfieldError
from pointfield.splats.gsplat_rasterizer import choose_rasterizer, gsplat_usable, rasterization_gsplat
from pointfield.splats.rasterizer import rasterization


def test_auto_picks_pointfield_where_gsplat_cannot_run():
    assert choose_rasterizer("auto", torch.device("cpu")) == "pointfield"
    assert choose_rasterizer("pointfield", torch.device("cpu")) == "pointfield"


def test_asking_for_gsplat_where_it_cannot_run_says_why():
    with pytest.raises(PointfieldError, match="cannot render with gsplat: .*--rasterizer pointfield"):
        choose_rasterizer("gsplat", torch.device("cpu"))


def test_an_unknown_rasterizer_is_named():
    with pytest.raises(PointfieldError, match="unknown rasterizer 'opengl'"):
        choose_rasterizer("opengl", torch.device("cpu"))


@pytest.mark.skipif(not (torch.cuda.is_available() and gsplat_usable(torch.device("cuda"))),
                    reason="needs gsplat and a CUDA device")
def test_gsplat_and_pointfield_render_the_same_images_on_cuda():
    generator = torch.Generator().manual_seed(0)
    count = 400
    means = torch.randn(count, 3, generator=generator) * 0.6 + torch.tensor([0.0, 0.0, 4.0])
    quats = torch.randn(count, 4, generator=generator)
    scales = torch.rand(count, 3, generator=generator) * 0.2 + 0.03
    opacities = torch.rand(count, generator=generator) * 0.9 + 0.05
    coefficients = torch.randn(count, 16, 3, generator=generator) * 0.3
    Ks = torch.tensor([[[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]]])
    splats = [t.cuda() for t in (means, quats, scales, opacities, coefficients)]
    cameras = [torch.eye(4)[None].cuda(), Ks.cuda()]
    background = torch.tensor([1.0, 1.0, 1.0], device="cuda")
    with torch.no_grad():
        ours = rasterization(*splats, *cameras, 64, 48, sh_degree=3, backgrounds=background)
        theirs = rasterization_gsplat(*splats, *cameras, 64, 48, sh_degree=3, backgrounds=background)
    for name, a, b in zip(("colors", "depths", "alphas"), ours[:3], theirs[:3]):
        assert a.shape == b.shape, name
        # Both composite in float32 with the same rules; they differ in rounding and in how a
        # pixel at exactly a threshold is treated.
        torch.testing.assert_close(a, b, atol=2e-3, rtol=1e-3, msg=name)
    torch.testing.assert_close(ours[3]["means2d"], theirs[3]["means2d"], atol=1e-3, rtol=1e-4)
