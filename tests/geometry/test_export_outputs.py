"""``nerf export`` and ``splat export`` never replace a file silently: an output that exists is
refused unless ``--overwrite``, before any rendering, as ``scene from-images`` and the streaming
verbs refuse theirs; one file named for two outputs is refused always."""

from __future__ import annotations

from pointfield.cli import main
from pointfield.clouds import read


def test_splat_export_refuses_to_replace_the_splat_file_with_a_mesh(splat_run, tmp_path, capsys):
    # The README once wrote the splats to lego.ply and, two lines later, a mesh to lego.ply.
    splats = tmp_path / "lego.ply"
    assert main(["splat", "export", str(splat_run), "--out", str(splats)]) == 0
    before = splats.read_bytes()
    assert main(["splat", "export", str(splat_run), "--mesh", str(splats), "--resolution", "16", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert f"pointfield: error: {splats} already exists" in err and "--overwrite" in err
    assert splats.read_bytes() == before


def test_overwrite_replaces_an_export(splat_run, tmp_path):
    centres = tmp_path / "centres.ply"
    centres.write_text("not a cloud")
    assert main(["splat", "export", str(splat_run), "--centres", str(centres)]) == 1
    assert centres.read_text() == "not a cloud"
    assert main(["splat", "export", str(splat_run), "--centres", str(centres), "--overwrite"]) == 0
    assert len(read(centres).points) > 0


def test_nerf_export_refuses_an_existing_output_before_opening_the_run(tmp_path, capsys):
    # The refusal comes first: a folder that is not a run would be the next error, after minutes of work on a real one.
    cloud = tmp_path / "lego-cloud.ply"
    cloud.write_text("kept")
    folder = tmp_path / "not-a-run"
    folder.mkdir()
    assert main(["nerf", "export", str(folder), "--cloud", str(cloud)]) == 1
    assert f"{cloud} already exists" in capsys.readouterr().err
    assert cloud.read_text() == "kept"


def test_one_file_for_two_outputs_is_refused_even_with_overwrite(tmp_path, capsys):
    folder = tmp_path / "run"
    folder.mkdir()
    same = tmp_path / "lego.ply"
    assert main(["nerf", "export", str(folder), "--cloud", str(same), "--mesh", str(same), "--overwrite"]) == 1
    assert "one file is named for two outputs" in capsys.readouterr().err
    assert not same.exists()
