"""Gaussian splats in the browser: the Gaussians themselves, drawn by viser's Gaussian-splat node.

The browser sorts and blends the splats itself, so a splat file or run turns as smoothly as the
machine's graphics allow, with nothing rendered on the server. It draws each Gaussian with its
view-independent colour -- spherical-harmonic degree 0, ``rgb = 0.5 + C0 * sh_dc`` -- so
view-dependent highlights are missing; a splat run's *show* dropdown switches to the server's
full render (every SH degree, depth, opacity: :mod:`pointfield.viewer.fields`).

viser takes world-space covariances ``Sigma = R S S^T R^T``
(:func:`pointfield.splats.gaussians.covariances`), colours and opacities in [0, 1].
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pointfield.fields.encodings.spherical_harmonics import C0
from pointfield.splats.gaussians import Gaussians, covariances
from pointfield.splats.mip import drawn
from pointfield.splats.ply import read_splats
from pointfield.viewer.server import Viewer


def splat_arrays(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """``centers`` (N, 3), ``covariances`` (N, 3, 3), ``rgbs`` (N, 3) and ``opacities`` (N, 1), float32 numpy.

    Scales and opacities are the drawn ones: with Mip-Splatting's 3D filter where the run has it.
    """
    with torch.no_grad():
        scales, opacities = drawn(gaussians)
        return {
            "centers": gaussians.means.float().cpu().numpy(),
            "covariances": covariances(gaussians.quats, scales).float().cpu().numpy(),
            "rgbs": (0.5 + C0 * gaussians.sh_dc[:, 0, :]).clamp(0, 1).float().cpu().numpy(),
            "opacities": opacities[:, None].float().cpu().numpy(),
        }


def add_gaussians(viewer: Viewer, gaussians: Gaussians, node: str) -> Any:
    """Add ``gaussians`` to the page as viser's Gaussian-splat node ``node`` (display coordinates)."""
    arrays = splat_arrays(gaussians)
    arrays["centers"] = (arrays["centers"] - viewer.origin).astype(np.float32)
    return viewer.server.scene.add_gaussian_splats(node, **arrays)


@dataclass
class SplatFileView:
    """A splat file on the page: its Gaussians and their node."""

    gaussians: Gaussians
    node: Any


def show_splat_file(viewer: Viewer, path: str | os.PathLike[str], name: str) -> SplatFileView:
    """Add a standard splat ``.ply`` to the page; the camera starts looking at its middle 90 %."""
    path = Path(path)
    gaussians = read_splats(path)
    means = gaussians.means.detach().double().numpy()
    low, high = np.percentile(means, 5, axis=0), np.percentile(means, 95, axis=0)
    viewer.recentre(low, high)
    viewer.grow(low, high)
    with viewer.server.gui.add_folder(name):
        viewer.server.gui.add_markdown(
            f"{len(gaussians):,} Gaussians, SH degree {gaussians.sh_degree} (drawn with degree 0)  \n{path.name}"
        )
    node = add_gaussians(viewer, gaussians, f"/{name}/splats")
    centre = (low + high) / 2
    size = float(np.linalg.norm(high - low)) or 1.0
    viewer.first_look(centre, centre + size * np.array([0.0, -0.8, 0.5]), up=(0.0, 0.0, 1.0))
    return SplatFileView(gaussians, node)
