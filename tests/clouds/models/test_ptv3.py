"""Point Transformer V3 in plain PyTorch: curves that serialize, a neighbour gather that is a sparse
convolution, scores that belong to each point whatever the order, and a backbone that learns rooms
through ``pointfield segment train --model ptv3``."""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from scene_rooms import TINY

import pointfield
from pointfield.cli import main
from pointfield.clouds.models import build_model
from pointfield.clouds.models.ptv3 import (
    DEPTH,
    NEIGHBOUR_OFFSETS,
    ORDERS,
    PTv3Segmenter,
    _GatherNeighbours,
    gather_neighbours,
    hilbert_code,
    serialize,
    voxel_neighbours,
)
from pointfield.clouds.scene_tasks import train_scenes
from pointfield.clouds.synthetic_scenes import ROOM_CLASSES
from pointfield.errors import PointfieldError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def distinct_voxels(count: int, side: int, clouds: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """``count`` random distinct (cloud, x, y, z) cells, or fewer after removing repeats."""
    generator = torch.Generator().manual_seed(seed)
    cells = torch.cat([torch.randint(0, clouds, (count, 1), generator=generator),
                       torch.randint(0, side, (count, 3), generator=generator)], dim=1)
    cells = torch.unique(cells, dim=0)[torch.randperm(len(torch.unique(cells, dim=0)), generator=generator)]
    return cells[:, 1:], cells[:, 0]


@pytest.mark.parametrize("order", ORDERS)
def test_serialization_is_a_permutation_that_walks_each_cloud_and_its_inverse_restores_order(order):
    grid, batch = distinct_voxels(400, 9, 3)
    serial, inverse = serialize(grid, batch, order)
    assert torch.equal(torch.sort(serial).values, torch.arange(len(grid)))
    assert torch.equal(serial[inverse], torch.arange(len(grid)))
    assert torch.equal(grid[serial][inverse], grid)
    assert (batch[serial].diff() >= 0).all()  # cloud by cloud
    shuffled = torch.randperm(len(grid), generator=torch.Generator().manual_seed(1))
    again, _ = serialize(grid[shuffled], batch[shuffled], order)
    assert torch.equal(grid[shuffled][again], grid[serial])  # the order is the cells', not the storage's


def test_consecutive_hilbert_cells_share_a_face_and_z_order_is_not_so():
    cube = torch.tensor(list(itertools.product(range(8), repeat=3)))
    walk = cube[hilbert_code(cube, DEPTH).argsort()]
    assert (walk.diff(dim=0).abs().sum(dim=1) == 1).all()
    z_walk = cube[serialize(cube, torch.zeros(len(cube), dtype=torch.int64), "z")[0]]
    assert (z_walk.diff(dim=0).abs().sum(dim=1) > 1).any()


def test_the_27_neighbour_gather_finds_what_a_brute_force_search_finds():
    grid, batch = distinct_voxels(300, 6, 2, seed=2)
    table = voxel_neighbours(grid, batch)
    count = len(grid)
    for i in range(count):
        for k, offset in enumerate(NEIGHBOUR_OFFSETS):
            match = torch.nonzero(((grid == grid[i] + offset).all(dim=1)) & (batch == batch[i])).flatten()
            assert table[i, k].item() == (match.item() if len(match) else count), (i, k)
    features = torch.randn(count, 4)
    gathered = gather_neighbours(features, table)
    assert torch.equal(gathered[:, 13], features)  # the centre offset is the voxel itself
    assert (gathered[table == count] == 0).all()  # empty cells read as zeros


def test_the_gathers_backward_equals_autograd_through_plain_indexing():
    grid, batch = distinct_voxels(300, 6, 2, seed=3)
    table = voxel_neighbours(grid, batch)
    features = torch.randn(len(grid), 5, dtype=torch.float64, requires_grad=True)
    weights = torch.randn(len(grid), 27, 5, dtype=torch.float64)
    (fast,) = torch.autograd.grad((gather_neighbours(features, table) * weights).sum(), features)
    (plain,) = torch.autograd.grad((_GatherNeighbours.reference(features, table) * weights).sum(), features)
    assert torch.allclose(fast, plain, atol=1e-12)


def clouds(batch: int = 2, points: int = 300, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    xyz = torch.randn(batch, points, 3, generator=generator)
    xyz = xyz / xyz.norm(dim=-1, keepdim=True) * torch.rand(batch, points, 1, generator=generator) ** (1 / 3)
    return xyz, torch.randn(batch, points, 2, generator=generator)


def test_each_points_scores_do_not_depend_on_the_order_of_the_points():
    torch.manual_seed(0)
    model = PTv3Segmenter(4, 2, voxel=0.1, patch=16).eval()
    xyz, features = clouds()
    mask = torch.ones(2, 300, dtype=torch.bool)
    mask[1, 250:] = False  # the second cloud is padded
    order = torch.randperm(300)
    with torch.no_grad():
        scores = model(xyz, features, mask)
        shuffled = model(xyz[:, order], features[:, order], mask[:, order])
    assert torch.allclose(scores[:, order][mask[:, order]], shuffled[mask[:, order]], atol=1e-5)
    assert (scores[1, 250:] == 0).all()
    assert scores[0].std(dim=0).min() > 0  # per point, not one answer for the whole cloud


def test_a_clouds_scores_do_not_depend_on_the_other_clouds_of_its_batch():
    torch.manual_seed(0)
    model = PTv3Segmenter(4, 2, voxel=0.1, patch=16).eval()
    xyz, features = clouds()
    with torch.no_grad():
        together = model(xyz, features)
        alone = model(xyz[:1], features[:1])
    assert torch.allclose(together[:1], alone, atol=1e-5)


def test_ptv3_refuses_to_classify_and_a_crop_too_wide_for_its_codes():
    with pytest.raises(PointfieldError, match="does not classify"):
        build_model("ptv3", "classify", 4)
    model = PTv3Segmenter(3, voxel=1e-5).eval()
    with pytest.raises(PointfieldError, match="larger voxel"):
        model(torch.tensor([[[0.0, 0, 0], [1.0, 0, 0]]]))


def test_object_training_refuses_ptv3_with_one_line_naming_what_it_is_for(tmp_path, capsys):
    assert main(["segment", "train", "--model", "ptv3", "--out", str(tmp_path / "run"), "--no-progress"]) != 0
    assert "'ptv3' segments scenes" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def run(rooms, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "ptv3"
    assert main(["segment", "train", str(rooms), "--out", str(out), "--model", "ptv3", "--epochs", "4",
                 "--lr", "0.002", *TINY]) == 0
    return out


def test_segment_train_model_ptv3_runs_end_to_end_from_the_command_line(run, capsys):
    config = json.loads((run / "config.json").read_text())
    assert config["model"] == "ptv3"
    assert config["model_options"]["voxel"] == pytest.approx(0.12 / 1.5)  # the data's grid, in crop units
    assert (run / "checkpoints" / "last.pt").is_file() and (run / "prediction.png").is_file()
    assert main(["segment", "eval", str(run), "--device", "cpu"]) == 0
    assert "mIoU" in capsys.readouterr().out


def test_ptv3_learns_rooms_loss_falls_and_miou_beats_the_majority_guess(run):
    final = json.loads((run / "metrics.json").read_text())
    losses = [json.loads(line)["train_loss"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert losses[-1] < 0.8 * losses[0], losses
    majority_miou = final["majority_class_accuracy"] / len(ROOM_CLASSES)  # one class right, the rest 0
    assert final["miou"] > majority_miou + 0.1, (final["miou"], majority_miou)


def test_a_ptv3_run_predicts_a_shuffled_scan_with_each_points_own_label(run, rooms, tmp_path):
    source = next((rooms / "test").glob("*.ply"))
    scan = pointfield.read(source)
    order = np.random.default_rng(1).permutation(len(scan))
    shuffled = tmp_path / "shuffled.ply"
    pointfield.write(shuffled, scan.select(order))
    opened = pointfield.load_run(run, device="cpu")
    a = pointfield.read(opened.predict([source], out=tmp_path / "a.ply")[0]["output"])
    b = pointfield.read(opened.predict([shuffled], out=tmp_path / "b.ply")[0]["output"])
    assert np.array_equal(a.fields["label"][order], b.fields["label"])
    assert np.allclose(a.fields["confidence"][order], b.fields["confidence"], atol=1e-5)


def test_a_ptv3_run_resumes_from_its_checkpoint_for_more_epochs(run, rooms, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(run, out)
    final = train_scenes([rooms], out=out, resume=True, epochs=5, progress=False, device="cpu")
    epochs = [json.loads(line)["epoch"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert epochs == [1, 2, 3, 4, 5] and final["epochs"] == 5 and final["model"] == "ptv3"
