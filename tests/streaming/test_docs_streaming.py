"""docs/streaming.md's Python example runs as a script (its ``__main__`` guard lets Dask's worker
processes import the file again), defines every name it uses, and the table's StreamingFallback
warning is what converting a binary_compressed PCD really gives."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.streaming import StreamingFallback, convert_folder

PAGE = Path(__file__).resolve().parents[2] / "docs" / "streaming.md"


def python_block() -> str:
    (block,) = re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.DOTALL)
    return block


def test_the_example_runs_as_a_script_with_two_dask_workers(shared_data, tmp_path, checkout_environment):
    (tmp_path / "city.laz").symlink_to(shared_data / "las" / "autzen_trim.laz")
    script = tmp_path / "guide.py"
    script.write_text(python_block())
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                            env=checkout_environment, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Nanny failed" not in result.stderr
    in_memory = pointfield.read(tmp_path / "city-50cm.laz")
    assert len(in_memory) == len(pointfield.read(tmp_path / "city-50cm-dask.laz")) > 0
    assert (tmp_path / "tiles" / "tiles.json").is_file()
    copy, original = pointfield.read(tmp_path / "city-copy.laz"), pointfield.read(tmp_path / "city.laz")
    assert np.array_equal(copy.points, original.points)


def test_a_folder_convert_says_which_files_were_held_whole(shared_data, tmp_path):
    folder = tmp_path / "scans"
    folder.mkdir()
    (folder / "milk.pcd").symlink_to(shared_data / "pcd" / "pcl_milk_binary_compressed.pcd")
    with pytest.warns(StreamingFallback, match=r"1 of the files could not be streamed .*milk.pcd"):
        convert_folder(folder, tmp_path / "out", ".ply")
    assert len(pointfield.read(tmp_path / "out" / "milk.ply")) == 13_704
