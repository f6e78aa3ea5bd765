"""Whole scans predicted within a memory budget: tile by tile with a halo, the labels those of the scan
read whole; the LAS class table in the header; a budget too small for one crop refused in one line."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import LabelledClouds
from pointfield.clouds.formats.chunked import concatenate
from pointfield.clouds.scene_streaming import TILE_BYTES_PER_POINT, Histogram, inference_bytes
from pointfield.clouds.synthetic_scenes import ROOM_CLASSES

pytestmark = pytest.mark.usefixtures("one_torch_thread")

PINNED_RESIDENT = 300 << 20
COPIES = 3
# What a point of this scan costs in a tile: the run's estimate beside its spill record (float32 x y z,
# uint8 colour, float32 intensity, int64 row) read and copied.
TILE_POINT_BYTES = TILE_BYTES_PER_POINT + 2 * 27


@pytest.fixture(scope="module")
def strip(rooms, tmp_path_factory) -> Path:
    """The lowest half metre of a band 1.5 m wide across a test room, three times along x 7.5 m
    apart: a scan 20 m long with some of every class that reaches the floor."""
    room = pointfield.read(sorted((rooms / "test").glob("*.ply"))[0])
    room = room.select((room.points[:, 2] < 0.5) & (room.points[:, 1] < 1.5))
    shift = np.array([7.5, 0.0, 0.0], np.float32)
    scan = concatenate([PointCloud(room.points + i * shift, room.fields) for i in range(COPIES)])
    path = tmp_path_factory.mktemp("strip") / "strip.ply"
    pointfield.write(path, scan)
    return path


def points(path: Path) -> int:
    return len(pointfield.read(path))


def small_run(run_dir: Path):
    """The rooms run with crops of 32 points on a 0.4 m grid, one crop per batch: a crop's scores
    then do not depend on which crops share its batch (batched crops move them by float rounding),
    so that the tiles' labels can be held to the whole scan's exactly."""
    run = pointfield.load_run(run_dir, device="cpu")
    run.config.update(batch_size=1, grid=0.4, points=32)
    return run


@pytest.fixture(scope="module")
def predicted(rooms_run, strip, tmp_path_factory):
    """The strip predicted read whole and streamed, both into LAZ files."""
    out = tmp_path_factory.mktemp("predicted")
    run = small_run(rooms_run)
    whole = run.predict([strip], out=out / "whole.laz")[0]
    with pytest.MonkeyPatch.context() as patch:
        # The budget's arithmetic starts from this process's size, which a test runner's worker grows
        # as it goes: pinned, a budget buys the same tiles every time.
        patch.setattr("pointfield.clouds.scene_streaming.resident_bytes", lambda: PINNED_RESIDENT)
        # Room for nine tenths of the scan: a tile of three 3 m cover cells with its 5.3 m halo fits
        # (four fifths of the points), the whole scan does not.
        budget = PINNED_RESIDENT + inference_bytes(run.config, 1) + int(0.9 * points(strip) * TILE_POINT_BYTES)
        streamed = run.predict([strip], out=out / "streamed.laz", memory=budget)[0]
    return whole, streamed


def test_a_scan_predicted_tile_by_tile_gets_the_labels_of_the_scan_read_whole(predicted, strip):
    whole, streamed = predicted
    assert "tiles" not in whole and streamed["tiles"] >= 3, streamed  # the budget forced tiles
    assert streamed["tile_size"] == 9.0 and streamed["halo"] >= 1.5  # three cover cells; a radius or more
    a, b = pointfield.read(whole["output"]), pointfield.read(streamed["output"])
    assert len(a) == len(b) == len(pointfield.read(strip))
    assert np.array_equal(a.points, b.points)  # the file's order kept
    # Every point's windows, chunks and grid cell are the whole scan's: with one crop per batch the
    # votes are the same sums of the same numbers, so labels and confidences agree exactly.
    assert np.array_equal(a.fields["classification"], b.fields["classification"])
    assert np.array_equal(a.fields["confidence"], b.fields["confidence"])
    assert whole["classes"] == streamed["classes"]
    assert len(np.unique(b.fields["classification"])) >= 2


def test_las_outputs_carry_the_class_table_in_the_classification_lookup_vlr(predicted, rooms_run):
    for answer in predicted:
        header = laspy.read(answer["output"]).header
        (lookup,) = [v for v in header.vlrs if (v.user_id, v.record_id) == ("LASF_Spec", 0)]
        assert len(lookup.record_data_bytes()) == 256 * 16  # the spec's 256 entries of 16 bytes
        assert {code: lookup[code] for code in range(len(ROOM_CLASSES))} == dict(enumerate(ROOM_CLASSES))
        assert Path(answer["output"] + ".classes.json").is_file()


def test_a_labelled_las_without_a_class_table_takes_the_names_in_its_vlr(predicted, tmp_path):
    las = tmp_path / "scans" / "labelled.laz"
    las.parent.mkdir()
    las.write_bytes(Path(predicted[1]["output"]).read_bytes())  # no classes.json beside it
    dataset = LabelledClouds([las.parent], "train")
    assert dataset.classes == list(ROOM_CLASSES) and dataset.codes == list(range(len(ROOM_CLASSES)))


def test_a_budget_too_small_for_one_crop_is_refused_in_one_line_naming_what_it_needs(rooms_run, strip, tmp_path,
                                                                                     capsys):
    assert main(["segment", "predict", str(rooms_run), str(strip), "--out", str(tmp_path / "x.laz"),
                 "--memory", "300M", "--device", "cpu", "--no-progress"]) == 1
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "--memory 300M is too small" in error and "give --memory" in error, error
    assert not (tmp_path / "x.laz").exists()


def test_percentiles_from_histograms_match_numpy_for_integers_and_nearly_for_floats():
    rng = np.random.default_rng(0)
    counts = rng.integers(0, 4000, 10_000).astype(np.uint16)
    exact = Histogram(counts.min(), counts.max(), integer=True)
    for part in np.array_split(counts, 7):  # windows of any size
        exact.add(part)
    assert exact.percentile(99) == pytest.approx(np.percentile(counts, 99), abs=1e-9)
    heights = rng.normal(0, 1, 10_000)
    near = Histogram(heights.min(), heights.max(), integer=False)
    near.add(heights)
    assert near.percentile(1) == pytest.approx(np.percentile(heights, 1), abs=np.ptp(heights) / 2**16 * 2)
