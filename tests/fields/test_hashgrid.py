"""The multiresolution hash encoding: resolutions, table layout, and fast paths against the reference."""

import math
import shutil
import warnings

import pytest
import torch

from pointfield.fields.encodings import hashgrid
from pointfield.fields.encodings.hashgrid import (
    PRIMES,
    HashEncoding,
    _HashGridFunction,
    level_layout,
    level_resolutions,
    reference_hash_encoding,
)


def _points(count: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    """Random points in [0, 1]^3 plus the awkward ones: on the faces 0 and 1, and outside the cube."""
    generator = torch.Generator().manual_seed(seed)
    inside = torch.rand(count, 3, generator=generator, dtype=dtype)
    edges = torch.tensor(
        [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.5], [1.0, 0.25, 0.0], [0.5, 0.5, 1.0]], dtype=dtype
    )
    outside = torch.tensor([[-0.5, 0.5, 0.5], [1.5, 2.0, -3.0], [0.3, -1e-3, 1.0 + 1e-3]], dtype=dtype)
    return torch.cat([inside, edges, outside])


def _small_encoding(dtype=torch.float64, backend: str = "eager", seed: int = 0) -> HashEncoding:
    """Four levels, 2^12 entries: the coarse two indexed directly, the fine two hashed."""
    torch.manual_seed(seed)
    encoding = HashEncoding(4, 2, 12, 4, 64, backend=backend).to(dtype)
    with torch.no_grad():  # features of order 1, so that errors are not hidden by tiny values
        encoding.table.uniform_(-1, 1)
    return encoding


# -- resolutions and layout ---------------------------------------------------------------------------


@pytest.mark.parametrize("levels, smallest, largest", [(16, 16, 2048), (8, 16, 128), (7, 10, 1000), (2, 3, 5)])
def test_resolutions_grow_geometrically_from_the_smallest_to_the_largest(levels, smallest, largest):
    resolutions = level_resolutions(levels, smallest, largest)
    assert len(resolutions) == levels
    assert resolutions[0] == smallest and resolutions[-1] == largest
    growth = (largest / smallest) ** (1 / (levels - 1))
    for level, resolution in enumerate(resolutions):
        assert resolution == math.floor(smallest * growth**level + 1e-6)
    assert resolutions == sorted(resolutions)


def test_the_papers_resolutions():
    assert level_resolutions(16, 16, 2048) == [
        16, 22, 30, 42, 58, 80, 111, 153, 212, 294, 406, 561, 776, 1072, 1482, 2048
    ]


def test_one_level_has_the_smallest_resolution():
    assert level_resolutions(1, 16, 2048) == [16]


@pytest.mark.parametrize("levels, smallest, largest", [(0, 16, 64), (4, 0, 64), (4, 64, 16)])
def test_impossible_resolutions_are_rejected(levels, smallest, largest):
    with pytest.raises(ValueError, match="levels >= 1"):
        level_resolutions(levels, smallest, largest)


@pytest.mark.parametrize("log2_table_size, direct_levels", [(12, 0), (15, 3), (19, 5), (24, 9)])
def test_levels_are_indexed_directly_exactly_where_their_power_of_two_grid_fits(log2_table_size, direct_levels):
    resolutions = level_resolutions(16, 16, 2048)
    table_size = 2**log2_table_size
    layout = level_layout(resolutions, log2_table_size)
    direct = 0
    for resolution, (entries, primes, mask) in zip(resolutions, layout):
        side = 2 ** math.ceil(math.log2(resolution + 1))  # power of two >= vertices per side
        if side**3 <= table_size:
            direct += 1
            assert (entries, primes, mask) == (side**3, (1, side, side * side), side**3 - 1)
            assert (resolution + 1) ** 3 <= entries  # every vertex has a row of its own
        else:
            assert (entries, primes, mask) == (table_size, PRIMES, table_size - 1)
    assert direct == direct_levels


@pytest.mark.parametrize("resolution", [1, 3, 16, 31, 58])
def test_direct_levels_give_every_vertex_its_own_row(resolution):
    [(entries, primes, mask)] = level_layout([resolution], 19)
    assert entries < 2**19, "this resolution should be indexed directly"
    axis = torch.arange(resolution + 1)
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")
    rows = (x * primes[0] ^ y * primes[1] ^ z * primes[2]) & mask
    assert rows.unique().numel() == (resolution + 1) ** 3
    assert int(rows.min()) >= 0 and int(rows.max()) < entries


def test_hashed_levels_use_the_xor_of_coordinates_times_primes():
    encoding = HashEncoding(1, 1, 6, 32, 32, backend="eager").double()
    assert encoding.level_sizes == [64]  # 33^3 vertices do not fit in 64 rows: hashed
    with torch.no_grad():
        encoding.table.copy_(torch.arange(64, dtype=torch.float64)[:, None])
    vertex = (5, 7, 11)
    expected_row = (vertex[0] * 1 ^ vertex[1] * 2654435761 ^ vertex[2] * 805459861) % 64
    # On a vertex, trilinear interpolation is that vertex's entry.
    point = torch.tensor([[c / 32 for c in vertex]], dtype=torch.float64)
    assert encoding(point).item() == expected_row


# -- the eager fast path against the reference ---------------------------------------------------------


def test_eager_encoding_equals_the_reference():
    encoding = _small_encoding()
    points = _points(500)
    torch.testing.assert_close(encoding(points), reference_hash_encoding(encoding, points), atol=1e-12, rtol=0)


def test_eager_gradient_wrt_the_table_equals_the_reference():
    encoding = _small_encoding()
    points = _points(500)
    upstream = torch.randn(points.shape[0], encoding.output_dim, generator=torch.Generator().manual_seed(1),
                           dtype=torch.float64)
    (fast,) = torch.autograd.grad((encoding(points) * upstream).sum(), encoding.table)
    (slow,) = torch.autograd.grad((reference_hash_encoding(encoding, points) * upstream).sum(), encoding.table)
    assert fast.abs().max() > 0
    torch.testing.assert_close(fast, slow, atol=1e-12, rtol=0)


def test_trilinear_weights_sum_to_one_so_a_constant_table_encodes_to_that_constant():
    encoding = _small_encoding()
    with torch.no_grad():
        encoding.table.fill_(0.75)
    torch.testing.assert_close(encoding(_points(100)), torch.full((108, 8), 0.75, dtype=torch.float64))


def test_points_outside_the_cube_are_clamped_onto_it():
    encoding = _small_encoding()
    outside = torch.tensor([[-0.5, 0.5, 1.5], [2.0, -3.0, 0.25]], dtype=torch.float64)
    clamped = torch.tensor([[0.0, 0.5, 1.0], [1.0, 0.0, 0.25]], dtype=torch.float64)
    torch.testing.assert_close(encoding(outside), encoding(clamped), atol=0, rtol=0)


def test_eager_backward_passes_gradcheck():
    encoding = HashEncoding(2, 2, 6, 2, 8, backend="eager").double()
    arguments = (encoding._resolution.double(), encoding._primes, encoding._mask, encoding._offset)
    points = _points(20, seed=3)
    table = encoding.table.detach().clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda t: _HashGridFunction.apply(points, t, *arguments), (table,))


@pytest.mark.parametrize("shape", [(7,), (2, 5), (3, 1, 4), (0,), (0, 6)])
def test_output_keeps_the_batch_shape_and_appends_levels_times_features(shape):
    encoding = HashEncoding(3, 4, 10, 2, 16, backend="eager")
    encoded = encoding(torch.rand(*shape, 3))
    assert encoding.output_dim == 12
    assert encoded.shape == (*shape, 12)


def test_the_table_holds_each_levels_rows_and_starts_small():
    encoding = HashEncoding(16, 2, 19, 16, 2048, backend="eager")
    assert encoding.table.shape == (sum(encoding.level_sizes), 2)
    assert encoding.level_sizes[-1] == 2**19 and max(encoding.level_sizes) == 2**19
    assert encoding.table.abs().max() <= 1e-4


# -- bad settings -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "options, message",
    [
        ({"backend": "cuda-kernel"}, "unknown hash-grid backend 'cuda-kernel'"),
        ({"log2_table_size": 0}, "log2_table_size must be in 1..24"),
        ({"log2_table_size": 25}, "log2_table_size must be in 1..24"),
        ({"levels": 0}, "levels >= 1"),
        ({"min_resolution": 0}, "min_resolution"),
        ({"min_resolution": 64, "max_resolution": 32}, "max_resolution"),
        ({"features_per_level": 0}, "features_per_level"),
    ],
)
def test_bad_settings_are_value_errors_that_say_what_was_expected(options, message):
    with pytest.raises(ValueError, match=message):
        HashEncoding(**options)


# -- the compiled fast path ---------------------------------------------------------------------------


@pytest.mark.skipif(
    not any(shutil.which(name) for name in ("c++", "g++", "clang++")),
    reason="torch.compile on a CPU needs a C++ compiler (c++, g++ or clang++); none is on PATH",
)
def test_compiled_encoding_and_its_gradient_equal_the_reference():
    encoding = _small_encoding(torch.float32, backend="compiled")
    points = _points(300, dtype=torch.float32)
    upstream = torch.randn(points.shape[0], encoding.output_dim, generator=torch.Generator().manual_seed(2))
    with warnings.catch_warnings():
        # A failed compilation falls back to eager with this warning; here it must not.
        warnings.filterwarnings("error", message="torch.compile of the hash encoding failed")
        fast = encoding(points)
    assert not hashgrid._FUSED_HASH_ENCODE.failed, "an earlier compilation failed: this ran eagerly"
    slow = reference_hash_encoding(encoding, points)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=0)
    (fast_grad,) = torch.autograd.grad((fast * upstream).sum(), encoding.table)
    (slow_grad,) = torch.autograd.grad((slow * upstream).sum(), encoding.table)
    torch.testing.assert_close(fast_grad, slow_grad, atol=1e-5, rtol=0)
