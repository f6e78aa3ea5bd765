"""The standard splat .ply layout: the real 3DGS file loads, and export -> load is exact."""

import numpy as np
import pytest
import torch

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.errors import FormatError
from pointfield.splats.gaussians import Gaussians
from pointfield.splats.ply import read_splat_mode, read_splats, write_splats

REAL_PLY = "gaussians/3dgs_point_cloud_iter7000.ply"


def test_the_real_3dgs_file_loads_with_9080_splats_of_sh_degree_3(shared_data):
    gaussians = read_splats(shared_data / REAL_PLY)
    assert len(gaussians) == 9080
    assert gaussians.sh_degree == 3
    assert gaussians.sh_rest.shape == (9080, 15, 3)
    assert torch.isfinite(gaussians.means).all()
    opacities = gaussians.opacities
    assert ((opacities > 0) & (opacities < 1)).all()


def test_export_of_the_real_file_is_byte_identical(shared_data, tmp_path):
    source = shared_data / REAL_PLY
    write_splats(tmp_path / "copy.ply", read_splats(source))
    assert (tmp_path / "copy.ply").read_bytes() == source.read_bytes()


def test_f_rest_is_read_channel_major(shared_data):
    gaussians = read_splats(shared_data / REAL_PLY)
    cloud = pointfield.read(shared_data / REAL_PLY)
    # f_rest_15 is the first higher coefficient of the green channel.
    np.testing.assert_array_equal(gaussians.sh_rest[:, 0, 1].detach().numpy(), cloud.fields["f_rest_15"])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_every_attribute_round_trips_exactly(tmp_path, degree):
    generator = torch.Generator().manual_seed(degree)
    count = 17
    gaussians = Gaussians(
        means=torch.randn(count, 3, generator=generator),
        quats=torch.randn(count, 4, generator=generator),
        log_scales=torch.randn(count, 3, generator=generator),
        opacity_logits=torch.randn(count, generator=generator),
        sh_dc=torch.randn(count, 1, 3, generator=generator),
        sh_rest=torch.randn(count, (degree + 1) ** 2 - 1, 3, generator=generator),
    )
    write_splats(tmp_path / "s.ply", gaussians)
    loaded = read_splats(tmp_path / "s.ply")
    for name, parameter in gaussians.parameters_by_name().items():
        assert torch.equal(parameter, getattr(loaded, name)), name


def test_a_ply_without_splat_properties_is_a_format_error(tmp_path):
    pointfield.write(tmp_path / "cloud.ply", PointCloud(np.zeros((3, 3), np.float32), {}))
    with pytest.raises(FormatError, match="not a splat file"):
        read_splats(tmp_path / "cloud.ply")


def test_a_wrong_number_of_f_rest_properties_is_a_format_error(tmp_path):
    fields = {name: np.zeros(2, np.float32) for name in
              ["f_dc_0", "f_dc_1", "f_dc_2", "f_rest_0", "opacity", "scale_0", "scale_1",
               "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]}
    pointfield.write(tmp_path / "bad.ply", PointCloud(np.zeros((2, 3), np.float32), fields))
    with pytest.raises(FormatError, match="f_rest"):
        read_splats(tmp_path / "bad.ply")


def test_the_rasterizer_mode_travels_in_a_header_comment_and_3dgs_files_are_classic(shared_data, tmp_path):
    assert read_splat_mode(shared_data / REAL_PLY) == {"antialiased": False, "screen_dilation": 0.3}
    gaussians = read_splats(shared_data / REAL_PLY)
    write_splats(tmp_path / "aa.ply", gaussians, {"antialiased": True, "screen_dilation": 0.1})
    assert read_splat_mode(tmp_path / "aa.ply") == {"antialiased": True, "screen_dilation": 0.1}
    assert b"comment pointfield rasterizer antialiased=1 screen_dilation=0.1\n" in (tmp_path / "aa.ply").read_bytes()[:4096]
    torch.testing.assert_close(read_splats(tmp_path / "aa.ply").means, gaussians.means, rtol=0, atol=0)


@pytest.mark.parametrize("comment", ["antialiased=yes screen_dilation=0.3", "antialiased=1 screen_dilation=-1",
                                     "antialiased=1", "antialiased=0 screen_dilation=nan"])
def test_a_malformed_mode_comment_is_a_format_error(tmp_path, comment):
    cloud = PointCloud(np.zeros((2, 3), np.float32), {}, metadata={"comments": [f"pointfield rasterizer {comment}"]})
    pointfield.write(tmp_path / "bad.ply", cloud)
    with pytest.raises(FormatError, match="bad.ply.*expected 'pointfield rasterizer antialiased=0|1"):
        read_splat_mode(tmp_path / "bad.ply")
