"""The rays a field trains on: every pixel of the training views, each ray jittered inside its pixel.

A camera's pixel integrates the light over its whole square, and anti-aliased images (every
real camera, Blender's renders, ``scene make``'s 2 x 2 supersampled ones) hold that mean. A
field trained only on rays through pixel centres is asked for the colour at the centre and
cannot match an edge pixel's mix: the demo's cube fell from 39.05 to 29.67 dB held out when its
images became anti-aliased. Instant-NGP and nerfstudio draw each training ray through a random
point of its pixel instead, so that over many steps the field sees the pixel's whole footprint;
:class:`TrainingRays` does that, with offsets drawn from the training step's seeded generator
(a resumed run draws what it would have drawn). Renders keep the pixel centres
(:meth:`pointfield.fields.rays.RayBundle.of_camera`), so they stay repeatable.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from pointfield.fields.rays import RayBundle, SceneExtent
from pointfield.scenes.scene import Scene


class TrainingRays:
    """Every pixel of ``frames`` of ``scene`` (frame by frame, row-major) with its colour, on ``device``.

    ``colors`` ``(R, 3)``; ``transparency`` ``(R,)`` float32 ``1 - alpha`` of each pixel, or None
    when an image has no alpha (:mod:`pointfield.training.opacity`); :meth:`rays` gives the rays of any of the R pixels, bounded by
    ``extent`` (:meth:`SceneExtent.near_far`), through their centres or jittered inside them.
    Holds three integers a pixel rather than its ray, and makes the rays of each batch when
    asked: a batch's rays cost far less than the field's samples along them.

    Example::

        >>> from pointfield.scenes.synthetic import synthetic_scene
        >>> scene = synthetic_scene("cube", views=2, size=4)
        >>> pixels = TrainingRays(scene, [0, 1], SceneExtent(scene.aabb), torch.device("cpu"))
        >>> len(pixels), pixels.colors.shape, len(pixels.rays(torch.arange(5)))
        (32, torch.Size([32, 3]), 5)
    """

    def __init__(self, scene: Scene, frames: Sequence[int], extent: SceneExtent, device: torch.device):
        frames = [int(i) for i in frames]
        self.extent = extent
        self.cameras = scene.cameras[frames].to(device)
        cameras, pixels, colors, transparencies = [], [], [], []
        for position, frame in enumerate(frames):
            height, width = int(scene.cameras.height[frame]), int(scene.cameras.width[frame])
            rows, columns = torch.meshgrid(torch.arange(height, dtype=torch.int32),
                                           torch.arange(width, dtype=torch.int32), indexing="ij")
            pixels.append(torch.stack([columns.reshape(-1), rows.reshape(-1)], dim=-1))
            cameras.append(torch.full((height * width,), position, dtype=torch.int32))
            image, alpha = scene.pixels(frame)
            colors.append(torch.from_numpy(image.reshape(-1, 3)))
            transparencies.append(None if alpha is None else torch.from_numpy(1 - alpha.reshape(-1)))
        self.camera_of = torch.cat(cameras).to(device)
        self.pixel_of = torch.cat(pixels).to(device)  # (R, 2) integer (u, v): the pixel's corner
        self.colors = torch.cat(colors).to(device)
        self.transparency = (None if not transparencies or any(t is None for t in transparencies)
                             else torch.cat(transparencies).to(device))

    def __len__(self) -> int:
        return self.colors.shape[0]

    def rays(self, indices: torch.Tensor, generator: torch.Generator | None = None) -> RayBundle:
        """The rays of pixels ``indices`` ``(B,)``: through ``(u + o_u, v + o_v)``, bounded by the extent.

        ``o ~ U[0, 1)^2`` per ray from ``generator`` (training: jittered inside the pixel), or
        ``o = (1/2, 1/2)`` without one (the pixel's centre, as renders are).
        """
        corner = self.pixel_of[indices].to(self.cameras.dtype)
        if generator is None:
            offsets = torch.full_like(corner, 0.5)
        else:
            offsets = torch.rand(corner.shape, generator=generator, dtype=torch.float64).to(corner)
        rays = self.cameras.rays_through(self.camera_of[indices].long(), corner + offsets)
        return RayBundle.within(rays.origins, rays.directions, self.extent)
