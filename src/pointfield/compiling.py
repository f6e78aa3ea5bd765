"""Fused kernels without a CUDA build: ``torch.compile`` where a compiler exists, eager otherwise.

The hot loops (the hash encoding and the ray marcher's occupancy test of the radiance fields,
the splat rasterizer's projection and tile binning) are written as plain tensor expressions. Eagerly, each operation is one pass over memory and leaves a
temporary behind; ``torch.compile`` (Inductor) fuses the expression into one loop, which on a
CPU is several times faster. It needs a C++ compiler (CPU) or Triton (CUDA) and compiles once
per shape family (seconds, then cached on disk). Where neither exists, or compilation fails,
the same function runs eagerly -- so results never depend on whether a compiler was found,
only the speed does.

``backend`` everywhere: "compiled" insists on compiling, "eager" never compiles, "auto"
(default) compiles where a compiler is available and falls back to eager, with one warning,
if compilation fails.
"""

from __future__ import annotations

import functools
import importlib.util
import shutil
import warnings
from collections.abc import Callable
from typing import Any

import torch

BACKENDS = ("auto", "compiled", "eager")

RECOMPILE_LIMIT = 32
"""Specialisations dynamo may keep per function: an unbounded model's field and proposal grids
alone need six of the hash encoding (levels, features, dtype, grad mode), past dynamo's default
of 8 with a few more, after which it would silently run the rest eagerly."""


def compiler_available(device: torch.device) -> bool:
    """Whether ``torch.compile`` can generate code for ``device`` here."""
    return _compiler_available_for(device.type)


@functools.cache  # asked on every call of a hot loop; a PATH search costs ~30 us
def _compiler_available_for(device_type: str) -> bool:
    if device_type == "cpu":
        return any(shutil.which(name) for name in ("c++", "g++", "clang++"))
    if device_type == "cuda":
        return importlib.util.find_spec("triton") is not None
    return False


class CompiledOrEager:
    """``function`` run through ``torch.compile(dynamic=True)`` where wanted, eagerly otherwise.

    ``what`` names the function in the warning given when compiling fails; after a failure the
    function runs eagerly for the rest of the process.
    """

    def __init__(self, function: Callable[..., Any], what: str):
        self.function, self.what = function, what
        self.failed = False
        self._compiled: Callable[..., Any] | None = None

    @property
    def ran_compiled(self) -> bool:
        """Whether a compiled version was built and has not failed (what benchmarks check)."""
        return self._compiled is not None and not self.failed

    def wanted(self, backend: str, device: torch.device) -> bool:
        if backend not in BACKENDS:
            raise ValueError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        if backend == "eager" or self.failed:
            return False
        return backend == "compiled" or compiler_available(device)

    def __call__(self, backend: str, device: torch.device, *arguments: Any,
                 eager: Callable[..., Any] | None = None) -> Any:
        """``function(*arguments)``, compiled if :meth:`wanted`; else (or on failure) ``eager`` (default: ``function``)."""
        if self.wanted(backend, device):
            if self._compiled is None:
                import torch._dynamo.config as dynamo_config

                for name in ("recompile_limit", "cache_size_limit"):
                    if hasattr(dynamo_config, name):
                        setattr(dynamo_config, name, max(getattr(dynamo_config, name), RECOMPILE_LIMIT))
                self._compiled = torch.compile(self.function, dynamic=True)
            try:
                return self._compiled(*arguments)
            except Exception as error:  # noqa: BLE001 - any compiler failure means: run eagerly
                self.failed = True
                warnings.warn(f"torch.compile of {self.what} failed ({type(error).__name__}: {error}); "
                              f"running it eagerly", RuntimeWarning, stacklevel=3)
        return (eager or self.function)(*arguments)
