"""docs/loading.md's code runs as written, on a folder of .ply / .pcd / .xyz clouds, and gives the
batches it says."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import pointfield
from pointfield.clouds import synthetic

PAGE = Path(__file__).resolve().parents[1] / "docs" / "loading.md"
CLASSES = {"chair": synthetic.sphere, "lamp": synthetic.cube_surface, "table": synthetic.torus}
SIZES = (100, 180, 260, 340, 420)  # points of a class's five files
SUFFIXES = (".ply", ".pcd", ".xyz")


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.DOTALL)


@pytest.fixture()
def my_clouds(tmp_path, monkeypatch, one_torch_thread):
    """``my_clouds/<class>/`` of five files each, of 100 to 420 points, in the three formats by turns."""
    for name, shape in CLASSES.items():
        for i, size in enumerate(SIZES):
            folder = tmp_path / "my_clouds" / name
            folder.mkdir(parents=True, exist_ok=True)
            pointfield.write(folder / f"{i:04d}{SUFFIXES[i % 3]}", shape(count=size, seed=i))
    monkeypatch.chdir(tmp_path)
    return tmp_path / "my_clouds"


def test_the_page_has_the_ten_line_loader_and_the_padded_batch_example():
    blocks = python_blocks()
    assert len(blocks) == 2
    assert len([line for line in blocks[0].splitlines() if line.strip()]) == 10


def test_the_pages_code_loads_the_folder_into_batches(my_clouds, capsys):
    first, second = python_blocks()
    namespace: dict = {}

    exec(first, namespace)  # noqa: S102  (the page's own code, run as a reader would)
    train, batch = namespace["train"], namespace["batch"]
    assert train.classes == sorted(CLASSES)
    assert train.held_out and len(train) == 12  # no test folder: the last of each class's five is held out
    assert {path.suffix for path in train.files} == set(SUFFIXES)
    assert tuple(batch.points.shape) == (12, 1024, 3)  # every cloud sampled (or padded) to 1,024 points
    assert batch.mask is None
    assert sorted(batch.labels.tolist()) == [0] * 4 + [1] * 4 + [2] * 4
    assert batch.points.norm(dim=-1).max() <= 1 + 3 * 0.05  # in the unit sphere, give or take the jitter
    assert capsys.readouterr().out.count("torch.Size([12, 1024, 3])") == 2  # one batch per epoch

    exec(second, namespace)  # noqa: S102
    every, batch, scores = namespace["every"], namespace["batch"], namespace["scores"]
    assert len(every) == 15 and every.split is None
    assert tuple(batch.points.shape) == (8, max(SIZES), 3)  # padded to the largest of the eight
    assert tuple(batch.mask.shape) == (8, max(SIZES))
    assert sorted(batch.mask.sum(dim=1).tolist()) == sorted([SIZES[i % 5] for i in range(8)])
    assert tuple(scores.shape) == (8, 3)
