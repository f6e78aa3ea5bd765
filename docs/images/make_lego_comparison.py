"""Regenerate docs/renders/lego-heldout.png: held-out lego views, ground truth beside each model's render.

Reads the held-out renders that ``benchmarks/bench_lego.py --out bench-output/lego-c`` leaves in
each run folder (``heldout/NNN.png``: truth | render | depth | opacity, 100 x 100 each).

Run: ``.venv/bin/python docs/images/make_lego_comparison.py [BENCH_OUTPUT]``
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

from pointfield.viz import image_grid, save_image

ROOT = Path(__file__).resolve().parents[2]
RUNS = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "bench-output" / "lego-c"
MODELS = {"tiny": "TinyNeRF", "ngp": "hash grid (ngp)", "splat": "Gaussian splats"}
VIEWS = ("010", "050", "080")
SCALE = 2  # 100 x 100 is small on a page; nearest-neighbour keeps the pixels honest


def panels(path: Path) -> list[np.ndarray]:
    """The 4 panels of a held-out PNG, each enlarged SCALE times."""
    strip = Image.open(path).convert("RGB")
    side = strip.height
    return [np.asarray(strip.crop((i * side, 0, (i + 1) * side, side)).resize((side * SCALE, side * SCALE),
                                                                             Image.NEAREST)) for i in range(4)]


images, labels = [], []
for view in VIEWS:
    images.append(panels(RUNS / "ngp" / "heldout" / f"{view}.png")[0])
    labels.append(f"view {int(view)}: ground truth")
    for model, name in MODELS.items():
        images.append(panels(RUNS / model / "heldout" / f"{view}.png")[1])
        labels.append(name)
save_image(ROOT / "docs" / "renders" / "lego-heldout.png", image_grid(images, labels, columns=1 + len(MODELS)))
