"""Rays and the samples along them: the one form each takes between cameras and fields.

Conventions (nerfstudio's vocabulary, nerfacc's layouts):

- A :class:`RayBundle` is R rays ``x(t) = origin + t direction`` with unit directions, each to be
  rendered between the distances ``near`` and ``far``.
- Those distances come from the scene, ray by ray, never from the cameras a field was trained
  with: a :class:`SceneExtent` (the box a field reconstructs, bounded or contracted around)
  gives every ray its own ``near`` and ``far`` (:meth:`SceneExtent.near_far`), so a camera
  nearer, farther or inside the box renders what is there. Training, ``run.render``, ``nerf
  render``, the viewer and the geometry exporters all make their rays this one way
  (:meth:`RayBundle.within`, :meth:`RayBundle.of_camera`).
- :class:`RaySamples` are intervals ``[t_start, t_end)`` along those rays, in one of two layouts:

  - **padded** -- ``t_starts``, ``t_ends`` ``(R, K)``: every ray has K samples (``ray_indices``
    is None). Stratified and proposal sampling give this.
  - **packed** -- ``t_starts``, ``t_ends`` ``(S,)`` with ``ray_indices`` ``(S,)``: sample s
    belongs to ray ``ray_indices[s]``, so rays of different lengths cost what they need (the
    occupancy-grid marcher gives this). A ray's samples are contiguous and in increasing t,
    rays in increasing order; a ray may have none, so ``num_rays`` is stored.

  The field is evaluated at one distance ``t`` in each interval, and depth is measured there:
  the interval's midpoint, unless the samples were made from points (:meth:`RaySamples.from_points`:
  NeRF's quadrature evaluates at ``t_i`` and lets the interval run to ``t_{i+1}``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pointfield.scenes.cameras import Cameras

NEAR_PLANE = 0.01
"""No ray starts nearer its camera than this fraction of the scene box's diagonal (the near
plane of a camera inside the box; nerfstudio's 0.05 on its unit-scaled scenes is about the same
share of their box)."""
UNBOUNDED_FAR = 1e3
"""Rays through an unbounded (contracted) scene end this many box radii away: where the
contracted space ends, in float32 terms -- real captures' backgrounds lie beyond any near/far
bound their poses came with."""


def ray_box_intersection(
    origins: torch.Tensor, directions: torch.Tensor, box: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances ``(R,)`` at which rays enter and leave the ``(2, 3)`` box (slab method).

    A ray that misses gets ``enter >= leave``; a ray starting inside gets ``enter < 0``.

    Example::

        >>> box = torch.tensor([[-1.0, -1, -1], [1, 1, 1]])
        >>> ray_box_intersection(torch.tensor([[0.0, 0, -3]]), torch.tensor([[0.0, 0, 1]]), box)
        (tensor([2.]), tensor([4.]))
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t_low = (box[0] - origins) / safe
    t_high = (box[1] - origins) / safe
    enter = torch.minimum(t_low, t_high).amax(dim=-1)
    leave = torch.maximum(t_low, t_high).amin(dim=-1)
    return enter, leave


@dataclass(frozen=True)
class SceneExtent:
    """Where along any ray a field's scene lies: the world ``box`` ``(2, 3)`` (min, max) and whether
    space beyond it is ``unbounded`` (contracted around it).

    :meth:`near_far` gives each ray its own interval, as nerfstudio's ``AABBBoxCollider`` and
    instant-ngp's aabb do for an object, and nerfacto's near and far planes for a capture:

    - bounded: from where the ray enters the box to where it leaves it, starting no nearer than
      the near plane (``NEAR_PLANE`` x the box's diagonal), so that a camera inside the box sees
      what is in front of it; a ray that misses the box gets ``near == far`` and so renders the
      background;
    - unbounded: from the near plane to ``UNBOUNDED_FAR`` box radii, the far end of the
      contracted space.

    Example (a camera 3 units from a unit box's centre, one inside it, one looking past it)::

        >>> extent = SceneExtent(((-1.0, -1, -1), (1, 1, 1)))
        >>> origins = torch.tensor([[0.0, 0, -3], [0, 0, 0], [0, 3, -3]])
        >>> near, far = extent.near_far(origins, torch.tensor([[0.0, 0, 1], [0, 0, 1], [0, 0, 1]]))
        >>> near, far
        (tensor([2.0000, 0.0346, 0.0346]), tensor([4.0000, 1.0000, 0.0346]))
    """

    box: tuple[tuple[float, float, float], tuple[float, float, float]]
    unbounded: bool = False

    def __post_init__(self) -> None:
        box = tuple(tuple(float(v) for v in corner) for corner in self.box)
        if len(box) != 2 or any(len(corner) != 3 for corner in box) or not all(
                high > low for low, high in zip(*box)):
            raise ValueError(f"a scene box needs min < max on every axis, got {self.box}")
        object.__setattr__(self, "box", box)

    @property
    def diagonal(self) -> float:
        """The box's diagonal, in scene units."""
        return float(torch.linalg.norm(torch.tensor(self.box[1]) - torch.tensor(self.box[0])))

    @property
    def near_plane(self) -> float:
        """The nearest any ray starts: ``NEAR_PLANE`` x the diagonal."""
        return NEAR_PLANE * self.diagonal

    def near_far(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``near``, ``far`` ``(R,)`` of rays ``origins``, unit ``directions`` ``(R, 3)`` (class docstring)."""
        count = origins.shape[0]
        near = torch.full((count,), self.near_plane, dtype=origins.dtype, device=origins.device)
        if self.unbounded:
            return near, torch.full_like(near, UNBOUNDED_FAR * 0.5 * self.diagonal)
        box = torch.tensor(self.box, dtype=origins.dtype, device=origins.device)
        enter, leave = ray_box_intersection(origins, directions, box)
        near = torch.maximum(enter, near)
        return near, torch.maximum(leave, near)  # a miss: an empty interval, so the background


@dataclass
class RayBundle:
    """R rays: ``origins`` ``(R, 3)``, unit ``directions`` ``(R, 3)``, distances ``near``, ``far`` ``(R,)``.

    Example::

        >>> rays = RayBundle(torch.zeros(4, 3), torch.tensor([[0.0, 0, 1]]).expand(4, 3),
        ...                  torch.full((4,), 2.0), torch.full((4,), 6.0))
        >>> len(rays), len(rays[1:3]), len(RayBundle.cat([rays, rays[:1]]))
        (4, 2, 5)
    """

    origins: torch.Tensor
    directions: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor

    def __post_init__(self) -> None:
        rays = self.origins.shape[0]
        if (self.origins.shape != (rays, 3) or self.directions.shape != (rays, 3)
                or self.near.shape != (rays,) or self.far.shape != (rays,)):
            raise ValueError(
                f"RayBundle needs origins and directions (R, 3) and near and far (R,), got "
                f"{tuple(self.origins.shape)}, {tuple(self.directions.shape)}, {tuple(self.near.shape)} "
                f"and {tuple(self.far.shape)}"
            )

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index: slice | torch.Tensor) -> RayBundle:
        """The rays at ``index``: a slice, a boolean mask ``(R,)`` or an index tensor."""
        return RayBundle(self.origins[index], self.directions[index], self.near[index], self.far[index])

    def to(self, device: torch.device | str) -> RayBundle:
        return RayBundle(self.origins.to(device), self.directions.to(device), self.near.to(device),
                         self.far.to(device))

    @property
    def device(self) -> torch.device:
        return self.origins.device

    @classmethod
    def within(cls, origins: torch.Tensor, directions: torch.Tensor, extent: SceneExtent) -> RayBundle:
        """Rays ``origins``, unit ``directions`` ``(R, 3)``, each between its own :meth:`SceneExtent.near_far`."""
        origins, directions = origins.float(), directions.float()
        return cls(origins, directions, *extent.near_far(origins, directions))

    @classmethod
    def of_camera(cls, cameras: Cameras, index: int, extent: SceneExtent) -> RayBundle:
        """Every pixel centre of camera ``index`` as a ray (row-major, ``H W`` rays), bounded by ``extent``."""
        rays = cameras.rays(index).reshape(-1)
        return cls.within(rays.origins, rays.directions, extent)

    @classmethod
    def cat(cls, bundles: list[RayBundle]) -> RayBundle:
        """The rays of ``bundles``, one after the other."""
        return cls(*(torch.cat([getattr(bundle, name) for bundle in bundles])
                     for name in ("origins", "directions", "near", "far")))


@dataclass
class RaySamples:
    """Intervals ``[t_starts, t_ends)`` along rays, padded ``(R, K)`` or packed ``(S,)`` (module docstring).

    ``ray_indices``: None (padded) or ``(S,)`` (packed). ``num_rays``: R; required when packed,
    read off the shape when padded. ``t_points``: where in each interval the field is evaluated,
    shaped like ``t_starts``; None means the midpoints.

    Example (two rays, packed: three samples on ray 0, none on ray 1)::

        >>> samples = RaySamples(torch.tensor([2.0, 3.0, 4.0]), torch.tensor([3.0, 4.0, 4.5]),
        ...                      ray_indices=torch.tensor([0, 0, 0]), num_rays=2)
        >>> samples.t, samples.deltas
        (tensor([2.5000, 3.5000, 4.2500]), tensor([1.0000, 1.0000, 0.5000]))
    """

    t_starts: torch.Tensor
    t_ends: torch.Tensor
    ray_indices: torch.Tensor | None = None
    num_rays: int | None = None
    t_points: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.ray_indices is None:
            if self.t_starts.ndim != 2:
                raise ValueError(f"padded samples need t_starts (R, K), got {tuple(self.t_starts.shape)}")
            self.num_rays = self.t_starts.shape[0]
        elif self.num_rays is None or self.t_starts.ndim != 1 or self.ray_indices.shape != self.t_starts.shape:
            raise ValueError(
                f"packed samples need t_starts and ray_indices (S,) and num_rays, got "
                f"{tuple(self.t_starts.shape)}, {tuple(self.ray_indices.shape)} and {self.num_rays}"
            )

    @classmethod
    def from_points(cls, t: torch.Tensor, far: torch.Tensor | float) -> RaySamples:
        """Padded samples at distances ``t`` ``(R, K)`` (sorted), each reaching to the next one, the last to ``far``.

        NeRF's quadrature: sample i stands for ``[t_i, t_{i+1})`` and is evaluated at ``t_i``, so the
        intervals tile ``[t_0, far)`` and a field opaque everywhere past ``t_0`` composites to
        opacity 1 whatever K is. ``far``: a float or ``(R,)``.

        Example::

            >>> RaySamples.from_points(torch.tensor([[2.0, 3.0, 5.0]]), 6.0).deltas
            tensor([[1., 2., 1.]])
        """
        far = torch.as_tensor(far, dtype=t.dtype, device=t.device).expand(t.shape[0])
        following = torch.cat([t[:, 1:], far[:, None]], dim=-1)
        # A point past far (or out of order) gets an empty interval rather than a negative one.
        return cls(t, torch.maximum(following, t), t_points=t)

    @classmethod
    def from_bin_edges(cls, edges: torch.Tensor) -> RaySamples:
        """Padded samples on the bins between consecutive ``edges`` ``(R, K + 1)``, evaluated at their midpoints."""
        return cls(edges[:, :-1], edges[:, 1:])

    @property
    def is_packed(self) -> bool:
        return self.ray_indices is not None

    def __len__(self) -> int:
        """The number of samples: S packed, R K padded."""
        return self.t_starts.numel()

    @property
    def t(self) -> torch.Tensor:
        """Where along its ray each sample is evaluated (and depth measured): ``t_points`` or the midpoints."""
        if self.t_points is not None:
            return self.t_points
        return 0.5 * (self.t_starts + self.t_ends)

    @property
    def deltas(self) -> torch.Tensor:
        """Interval lengths ``delta = t_end - t_start``, shaped like ``t_starts``."""
        return self.t_ends - self.t_starts

    def positions(self, rays: RayBundle) -> torch.Tensor:
        """World positions ``o + t d`` of the samples on ``rays``: ``(R, K, 3)`` padded, ``(S, 3)`` packed."""
        t = self.t
        if self.ray_indices is None:
            return rays.origins[:, None, :] + t[..., None] * rays.directions[:, None, :]
        return rays.origins[self.ray_indices] + t[:, None] * rays.directions[self.ray_indices]

    def view_directions(self, rays: RayBundle) -> torch.Tensor:
        """Each sample's ray direction: ``(R, K, 3)`` padded (a broadcast view), ``(S, 3)`` packed."""
        if self.ray_indices is None:
            return rays.directions[:, None, :].expand(*self.t_starts.shape, 3)
        return rays.directions[self.ray_indices]

    def select(self, keep: torch.Tensor) -> RaySamples:
        """The packed samples at ``keep`` (a boolean mask or index tensor over S), on the same rays."""
        if self.ray_indices is None:
            raise ValueError("select works on packed samples; call packed() first")
        points = None if self.t_points is None else self.t_points[keep]
        return RaySamples(self.t_starts[keep], self.t_ends[keep], self.ray_indices[keep], self.num_rays, points)

    def packed(self) -> RaySamples:
        """The same samples in the packed layout, ray by ray (packed samples come back as they are)."""
        if self.ray_indices is not None:
            return self
        rays, count = self.t_starts.shape
        ray_indices = torch.arange(rays, device=self.t_starts.device).repeat_interleave(count)
        points = None if self.t_points is None else self.t_points.reshape(-1)
        return RaySamples(self.t_starts.reshape(-1), self.t_ends.reshape(-1), ray_indices, rays, points)
