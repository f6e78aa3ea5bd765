"""The NeRF models by ``--model`` name: ``tiny``, ``nerf``, ``ngp`` and ``sdf`` (the neural SDF)."""

from __future__ import annotations

from typing import Any

from pointfield.fields.field import RadianceField
from pointfield.fields.nerf import NeRF, TinyNeRF
from pointfield.fields.ngp import InstantNGP
from pointfield.fields.sdf import NeuralSDF

MODELS: dict[str, type[RadianceField]] = {"tiny": TinyNeRF, "nerf": NeRF, "ngp": InstantNGP, "sdf": NeuralSDF}
"""``--model`` name -> class."""


def build_model(name: str, **options: Any) -> RadianceField:
    """The model called ``name`` ("tiny", "nerf", "ngp" or "sdf"), with constructor ``options``.

    Example::

        >>> build_model("tiny", samples=8).samples
        8
    """
    if name not in MODELS:
        raise ValueError(f"unknown NeRF model {name!r}; choose one of {', '.join(MODELS)}")
    return MODELS[name](**options)
