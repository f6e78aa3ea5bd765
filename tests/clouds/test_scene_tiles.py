"""A folder of tiles predicted as one scan on Dask: each tile's crops reach into its neighbours, so the labels are
those of the tiles merged into one cloud and no seam shows; a malformed tile is named in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.chunked import concatenate
from pointfield.clouds.scene_streaming import halo_of

pytestmark = pytest.mark.usefixtures("one_torch_thread")

COPIES = 6
STEP = 5.7  # the test room is 5.5 m long in x


@pytest.fixture(scope="module")
def tiles(rooms, tmp_path_factory) -> tuple[Path, Path, np.ndarray]:
    """The lowest 0.3 m of a band 1.5 m wide across the test room, six times along x: a scan 34 m long,
    cut at the quartiles of x (through the rooms) into four tile files; and the four concatenated, in
    the folder's order, as one file. Returns the folder, the file and the three cuts."""
    room = pointfield.read(sorted((rooms / "test").glob("*.ply"))[0])
    room = room.select((room.points[:, 2] < 0.3) & (room.points[:, 1] < 1.5))
    strip = concatenate([PointCloud(room.points + np.float32([i * STEP, 0, 0]), room.fields) for i in range(COPIES)])
    cuts = np.quantile(strip.points[:, 0], [0.25, 0.5, 0.75])
    which = np.searchsorted(cuts, strip.points[:, 0])
    folder = tmp_path_factory.mktemp("tiles")
    (folder / "tiles").mkdir()
    parts = [strip.select(which == i) for i in range(4)]
    for i, part in enumerate(parts):
        pointfield.write(folder / "tiles" / f"strip_{i}.ply", part)
    pointfield.write(folder / "merged.ply", concatenate(parts))
    return folder / "tiles", folder / "merged.ply", cuts


def small_run(run_dir: Path):
    """The rooms run with crops of 64 points on a 0.5 m grid, a 5.5 m halo: few crops, and the middle
    tiles, 8.5 m wide, have points farther than a halo from every cut."""
    run = pointfield.load_run(run_dir, device="cpu")
    run.config.update(batch_size=16, grid=0.5, points=64)
    return run


@pytest.fixture(scope="module")
def merged(rooms_run, tiles, tmp_path_factory) -> PointCloud:
    """The four tiles merged into one scan, predicted read whole."""
    out = tmp_path_factory.mktemp("merged") / "merged.ply"
    return pointfield.read(small_run(rooms_run).predict([tiles[1]], out=out)[0]["output"])


@pytest.fixture(scope="module")
def threads():
    """A dask.distributed cluster in this process (two workers of one thread): the tasks go through
    Dask's submit, scatter and gather as on worker processes, without their seconds of start-up."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        yield client


def labelled(folder: Path) -> PointCloud:
    return concatenate([pointfield.read(p) for p in sorted(folder.glob("*.ply"))])


def test_tiles_predicted_on_dask_get_the_labels_of_the_merged_scan(rooms_run, tiles, merged, threads, tmp_path):
    folder, _, _ = tiles
    run = small_run(rooms_run)
    answers = run.predict_tiles([folder], out=tmp_path / "tiles", client=threads)
    assert [Path(a["output"]).name for a in answers] == [f"strip_{i}.ply" for i in range(4)]
    # A tile reads its neighbours within the halo, not the whole folder.
    assert [[Path(n).name for n in a["neighbours"]] for a in answers] == [
        ["strip_1.ply"], ["strip_0.ply", "strip_2.ply"], ["strip_1.ply", "strip_3.ply"], ["strip_2.ply"]]
    tiled = labelled(tmp_path / "tiles")
    assert np.array_equal(tiled.points, merged.points)
    assert np.array_equal(tiled.fields["label"], merged.fields["label"])
    # The crops sharing a batch differ (a tile's are its own): every crop padded to the same size, only rounding could.
    np.testing.assert_allclose(tiled.fields["confidence"], merged.fields["confidence"], atol=1e-6)
    assert len(np.unique(merged.fields["label"])) >= 2
    assert (tmp_path / "tiles" / "strip_0.ply.classes.json").is_file()


def test_without_the_halo_the_tiles_differ_from_the_merged_scan_at_the_seams(rooms_run, tiles, merged, threads,
                                                                             tmp_path, monkeypatch):
    folder, _, cuts = tiles
    run = small_run(rooms_run)
    monkeypatch.setattr("pointfield.clouds.scene_tiles.halo_of", lambda config: 0.0)
    run.predict_tiles([folder], out=tmp_path / "tiles", client=threads)
    tiled = labelled(tmp_path / "tiles")
    differs = (tiled.fields["label"] != merged.fields["label"]) | ~np.isclose(
        tiled.fields["confidence"], merged.fields["confidence"], atol=1e-6)
    from_cut = np.abs(merged.points[:, :1] - cuts[None].astype(np.float32)).min(axis=1)
    assert differs.sum() > 100  # windows cut off at the tiles' borders
    # Beyond a halo of every cut a tile alone is the whole scan: the seam is there and only there.
    assert (from_cut > halo_of(run.config)).sum() > 100
    assert from_cut[differs].max() <= halo_of(run.config)


def test_a_malformed_tile_is_named_in_one_line_and_nothing_is_written(rooms_run, tiles, tmp_path, capsys):
    folder, _, _ = tiles
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "strip_0.ply").write_bytes((folder / "strip_0.ply").read_bytes())
    (bad / "strip_1.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 90\nend_header\n\x01")
    out = tmp_path / "out"
    assert main(["segment", "predict", str(rooms_run), str(bad), "--out", str(out), "--device", "cpu",
                 "--no-progress"]) == 1
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "strip_1.ply" in error, error
    assert not out.exists() or not any(out.iterdir())


def test_dask_options_without_tiles_are_refused_in_one_line(rooms_run, tiles, tmp_path, capsys):
    folder, _, _ = tiles
    assert main(["segment", "predict", str(rooms_run), str(folder / "strip_0.ply"), "--out", str(tmp_path),
                 "--workers", "2", "--device", "cpu"]) == 1
    assert "--workers and --scheduler predict the tiles of one scan" in capsys.readouterr().err


def test_a_format_error_crosses_from_a_worker_process_whole():
    import pickle

    from pointfield.errors import FormatError

    error = pickle.loads(pickle.dumps(FormatError("tiles/a.laz", "ends at byte 12")))
    assert isinstance(error, FormatError) and (error.path, error.reason) == ("tiles/a.laz", "ends at byte 12")
    assert str(error) == "tiles/a.laz: ends at byte 12"


def test_outputs_that_would_overwrite_the_tiles_are_refused_before_any_work(rooms_run, tiles, capsys):
    folder, _, _ = tiles
    assert main(["segment", "predict", str(rooms_run), str(folder), "--out", str(folder), "--device", "cpu"]) == 1
    assert "would overwrite a tile that its neighbours read" in capsys.readouterr().err
