"""What the streaming verbs tell a user about their options: a bad ``--memory`` is one error line,
a ``--random`` above the point count says so, and formats are named once ("las", not "las las")."""

from __future__ import annotations

import numpy as np
import pytest

import pointfield
from pointfield.cli import main
from pointfield.errors import OptionError, PointfieldError
from pointfield.streaming import downsample
from pointfield.streaming.memory import parse_memory, plan


@pytest.mark.parametrize(("memory", "expected"), [("100M", "too small"), ("lots", "expected a size such as 2G")])
def test_a_bad_memory_budget_is_one_error_line(tmp_path, data, capsys, memory, expected):
    code = main(["cloud", "downsample", str(data["laz"]), str(tmp_path / "x.laz"), "--voxel", "0.25",
                 "--memory", memory])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith("pointfield: error: --memory") and expected in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "x.laz").exists()


def test_memory_errors_are_pointfield_errors_and_still_value_errors():
    for call in (lambda: parse_memory("lots"), lambda: plan("100M", 64)):
        with pytest.raises(OptionError) as raised:
            call()
        assert isinstance(raised.value, PointfieldError) and isinstance(raised.value, ValueError)


def test_random_above_the_point_count_keeps_every_point_and_says_so(tmp_path, data):
    count = len(pointfield.read(data["las"]))
    with pytest.warns(UserWarning, match=rf"random={count + 1:,} is more than its {count:,} points; all of them are kept"):
        result = downsample(data["las"], tmp_path / "r.las", random=count + 1)
    assert result["output_points"] == count


def test_the_command_names_a_format_once(tmp_path, data, capsys):
    assert main(["cloud", "convert", str(data["laz"]), str(tmp_path / "strip.las")]) == 0
    out = capsys.readouterr().out
    assert ": las, " in out and "las las" not in out
    assert main(["cloud", "convert", str(data["las"]), str(tmp_path / "strip.laz")]) == 0
    assert ": las, laz, " in capsys.readouterr().out
    assert main(["cloud", "info", str(data["laz"]), "--stats", "--no-progress"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "format      las, laz" in lines and not any("las laz" in line for line in lines)


def test_merging_buffered_tiles_with_drop_buffers_gives_every_point_once(tmp_path, data, capsys):
    assert main(["cloud", "tile", str(data["laz"]), str(tmp_path / "tiles"), "--size", "25", "--buffer", "2",
                 "--no-progress"]) == 0
    tiles = sorted(str(p) for p in (tmp_path / "tiles").glob("*.laz"))
    original = pointfield.read(data["laz"])
    assert main(["cloud", "merge", *tiles, str(tmp_path / "twice.laz"), "--no-progress"]) == 0
    assert len(pointfield.read(tmp_path / "twice.laz")) > len(original)  # the buffers, once per tile
    assert main(["cloud", "merge", *tiles, str(tmp_path / "once.laz"), "--drop-buffers", "--no-progress"]) == 0
    once = pointfield.read(tmp_path / "once.laz")
    assert len(once) == len(original)
    assert np.array_equal(np.unique(once.fields["gps_time"]), np.unique(original.fields["gps_time"]))


def test_drop_buffers_needs_the_tiles_manifest(tmp_path, data, capsys):
    assert main(["cloud", "merge", str(data["laz"]), str(tmp_path / "x.laz"), "--drop-buffers"]) == 1
    assert "--drop-buffers needs the tiles.json" in capsys.readouterr().err
