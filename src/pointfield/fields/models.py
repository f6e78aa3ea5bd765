"""The NeRF models by ``--model`` name: ``tiny``, ``nerf`` and ``ngp``."""

from __future__ import annotations

from typing import Any

from pointfield.fields.field import RadianceField
from pointfield.fields.nerf import NeRF, TinyNeRF
from pointfield.fields.ngp import InstantNGP

MODELS: dict[str, type[RadianceField]] = {"tiny": TinyNeRF, "nerf": NeRF, "ngp": InstantNGP}
"""``--model`` name -> class."""


def build_model(name: str, **options: Any) -> RadianceField:
    """The model called ``name`` ("tiny", "nerf" or "ngp"), with constructor ``options``.

    Example::

        >>> build_model("tiny", samples=8).samples
        8
    """
    if name not in MODELS:
        raise ValueError(f"unknown NeRF model {name!r}; choose one of {', '.join(MODELS)}")
    return MODELS[name](**options)
