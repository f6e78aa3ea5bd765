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

# torch's CPU wheels run their parallel operations on GNU OpenMP, whose threads spin while they
# wait for each other. With another program busy on a core, a training step then runs many times
# slower than on a quiet machine; threads that sleep at once (PASSIVE) avoid that cliff
# (benchmarks/bench_threads.py measures both). libgomp reads the variable when torch loads it, so
# this runs before anything imports torch; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

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
