"""pointfield: a Python toolkit for 3D vision — point clouds, radiance fields, Gaussian splats.

The functions most people need first::

    import pointfield
    cloud = pointfield.read("scan.pcd")          # any supported format
    for chunk in pointfield.read_chunks("city.laz", points=1_000_000): ...  # bigger than memory
    pointfield.write("scan.ply", cloud)          # fields preserved, written atomically
    result = pointfield.register(scan, other)    # rigid motion scan -> other, with fitness and RMSE
    poses = pointfield.align([a, b, c]).poses    # many scans into one frame, loop closures included
    run = pointfield.load_run("runs/lego-ngp")   # any trained run: .render(cameras), .evaluate(), ...
    pointfield.classify.train(out="runs/shapes") # pointfield.classify / .segment: train, evaluate, predict
"""

import os
from typing import Any

# torch's CPU wheels run their parallel operations on GNU OpenMP, whose threads spin up to 300,000
# times while they wait for each other. With another program busy on a core, a training step then
# runs many times slower than on a quiet machine (13.5x for a splat step on 2 cores in the record). A spin of 10,000
# keeps the quiet machine's speed and most of the busy one's (benchmarks/bench_threads.py measures
# each choice). libgomp reads the variables when torch loads it, so this runs before anything
# imports torch; a waiting policy or spin count the user set is kept.
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["GOMP_SPINCOUNT"] = "10000"

from pointfield.clouds import Mesh, PointCloud, Records, read, write
from pointfield.errors import FormatError, PointfieldError
from pointfield.streaming import read_chunks
from pointfield.version import __version__

# The learning half needs torch, and registration scipy; they are imported on first use so that
# reading a cloud stays quick. pointfield.classify and pointfield.segment are modules of their own
# (``import pointfield.classify``).
_LEARNING = {"load_run": "pointfield.runs", "register": "pointfield.registration", "align": "pointfield.registration"}
_MODULES = ("classify", "segment")


def __getattr__(name: str) -> Any:
    import importlib

    if name in _LEARNING:
        return getattr(importlib.import_module(_LEARNING[name]), name)
    if name in _MODULES:
        return importlib.import_module(f"pointfield.{name}")
    raise AttributeError(f"module 'pointfield' has no attribute {name!r}")


__all__ = [
    "FormatError",
    "Mesh",
    "PointCloud",
    "PointfieldError",
    "Records",
    "__version__",
    "align",
    "classify",
    "load_run",
    "read",
    "read_chunks",
    "register",
    "segment",
    "write",
]
