"""The neural signed distance field (``--model sdf``): a hash-grid SDF rendered as NeuS renders it.

The surface is the zero level set of a signed distance ``f(x)`` (negative inside, positive
outside, as :mod:`pointfield.volumes.sdf` has it), so ``nerf export --mesh`` of this model is
one closed surface by construction (:mod:`pointfield.geometry.sdf_mesh`). The pieces, in the
order a ray meets them:

1. **Sampling**: the box is marched at a fixed step through the occupied cells of an
   :class:`~pointfield.fields.sampling.occupancy.OccupancyGrid`, as the hash-grid field (``ngp``)
   does; a cell is occupied while its largest possible logistic density (below) is not
   negligible, i.e. near the surface (instant-NSR's use of the grid for an SDF). Then *early
   termination*, as ngp's: one evaluation of ``f`` per sample without gradients estimates each
   section's opacity from consecutive samples of its ray, ``1 - Phi_s(f_{i+1}) / Phi_s(f_i)``
   (NeuS's estimate when it up-samples), and the samples behind which a ray's transmittance
   is below ``EARLY_STOP_TRANSMITTANCE`` are dropped before the full field runs, and so are
   those whose estimated weight ``T_i alpha_i`` is at most ``min_weight`` (:data:`MIN_WEIGHT`):
   the logistic tail in front of the surface, which the grid's band keeps occupied. That is
   NeuS's up-sampling (samples where the weight is) done by selection, and it is what lets a
   step of the same sample budget take more rays (ngp skips empty space the same way).
2. **The SDF network** (:class:`SDFNetwork`), on coordinates ``p = (x - c) / r`` that map the box
   into ``[-1, 1]^3`` (``c`` its centre, ``r`` half its longest side): the position and its
   multiresolution hash encoding (Instant-NGP) into a small ReLU MLP giving the signed
   distance ``f_p(p)`` (in those units; world distances are ``r f_p``) and 15 geometry features.
   Initialised as NeuS / IDR / SAL do (*geometric init*, Atzmon & Lipman 2020): the hash
   features enter with zero weights and the MLP starts as ``f_p(p) ~ |p| - radius``, a valid
   SDF of a sphere, so the eikonal term holds from the first step (the distance row of the last
   layer fitted to it by least squares, :meth:`SDFNetwork.geometric_init`).
3. **Normals** ``n = grad f / |grad f|``, by finite differences over a tetrahedron of points
   half a finest hash cell from the sample (:func:`tetrahedral_gradient`; NeuS2 and Neuralangelo
   take numerical gradients too): four evaluations whose backward is the hash grid's ordinary one,
   compiled like ngp's. ``gradient="autograd"`` takes autograd's instead, whose eikonal term
   needs the gradient of that gradient (double backward), which ``torch.compile`` cannot give:
   the hash encoding then runs eagerly (:class:`~pointfield.fields.encodings.hashgrid.HashEncoding`)
   and a sample costs 1.6 times as much on a CPU (:class:`NeuralSDF`).
4. **Colour**: spherical harmonics of the view direction, the normal and the geometry features
   into a 64-wide MLP, sigmoid RGB (NeuS's "idr" colour network, with SH for the direction).
5. **Opacity from the SDF**, NeuS's unbiased, occlusion-aware alpha (Wang et al. 2021,
   "NeuS", eq. 13, and its released code): with ``Phi_s(f) = sigmoid(s f)`` the logistic CDF,
   of sharpness ``s = exp(10 v)`` for a learned scalar ``v`` (started at 0.3, ``s = 20``),
   the section ``[t_i, t_i + delta_i]`` whose midpoint has SDF ``f_i`` and gradient ``g_i``
   has ends ``f_i -/+ cos_i delta_i / 2``, ``cos_i = min(d . g_i, 0)`` (only a surface the ray
   enters, never one it leaves, absorbs), and

       alpha_i = clip((Phi_s(f_i - cos_i delta_i / 2) - Phi_s(f_i + cos_i delta_i / 2))
                      / Phi_s(f_i - cos_i delta_i / 2), 0, 1)

   (all in box units ``p``). The compositor (:func:`~pointfield.fields.rendering.composite`)
   takes densities: ``sigma_i = -ln(1 - alpha_i) / delta_i`` is the constant density over the
   section with that opacity, so weights, depth and opacity come out of the one compositor.
   NeuS anneals ``cos`` from a half-sphere average, ``-(relu(1/2 - cos/2)(1 - r) + relu(-cos) r)``
   with ``r`` rising from 0 to 1 over its first steps; ``cos_anneal_steps`` does so (default 0:
   the final form throughout; no gain measured, docs/geometry.md). A
   ray's first section starts at ``f >= 0`` (``entry_outside``): outside the box is free space
   (the mesh export closes the surface there), so a ray that enters where ``f < 0`` meets the
   surface at the wall; the ratio alone is nearly 0 there, deep in the CDF's tail, where it
   depends on differences of ``f`` only and so pins no level.
6. **The eikonal loss** (Gropp et al. 2020), ``eikonal_weight * mean (|grad f_p| - 1)^2`` over
   the ray samples and ``eikonal_points`` uniform points of the box (which keep the SDF valid in
   the empty space no ray samples, so marching cubes finds no stray surfaces there), as the
   model's auxiliary loss; weight 0.1 as NeuS and instant-NSR use.
7. **Learning rates** (:meth:`NeuralSDF.parameter_groups`): the hash table at the run's, the
   MLPs and ``v`` at ``network_lr_fraction`` (a tenth) of it; ``sharpness_lr_fraction`` gives
   ``v`` a rate of its own (default None: the MLPs').

The model is a :class:`~pointfield.fields.field.RadianceField` like the others: trained by
``nerf train --model sdf`` through the same lifecycle and training rays, rendered by
``run.render(cameras)`` into rgb, depth and opacity.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from pointfield.fields.encodings.hashgrid import HashEncoding
from pointfield.fields.encodings.spherical_harmonics import sh_basis
from pointfield.fields.field import PROBE_COST, FieldOutput, RadianceField, checked_box
from pointfield.fields.ngp import DIRECTION_SH_DEGREE, EARLY_STOP_TRANSMITTANCE, GEOMETRY_FEATURES
from pointfield.fields.rays import RayBundle, RaySamples, SceneExtent
from pointfield.fields.rendering import composite, transmittance_from_optical_depth
from pointfield.fields.sampling.occupancy import OccupancyGrid, march_rays

INITIAL_VARIANCE = 0.3
"""NeuS's start for ``v`` in ``s = exp(10 v)``: ``s = 20``, a surface about a twentieth of the box's half-side thick."""
SOFTPLUS_BETA = 100.0
"""NeuS's softplus sharpness: ReLU-like, with a continuous gradient for the normals and the eikonal term."""
MAX_ALPHA = 1 - 1e-6
"""Alphas are capped here before ``-ln(1 - alpha)``, so that an opaque section has a finite density."""
GRADIENTS = ("finite-difference", "autograd")
"""How :meth:`NeuralSDF.sdf_and_gradient` takes ``grad f``: four offset evaluations, or autograd (module docstring, step 3)."""
NETWORK_LR_FRACTION = 0.1
"""The MLPs' and the sharpness's learning rate as a fraction of the hash table's (:meth:`NeuralSDF.parameter_groups`)."""
MIN_WEIGHT = 1e-3
"""Sections whose estimated rendering weight is at most this are skipped before the full field runs
(:meth:`NeuralSDF.terminated`): on the cube at 64 px, 300 steps, 27.97 dB held out against 25.21 without (758
rays a step against 444 at the same sample budget; 1e-2 gave 26.55; docs/geometry.md)."""
TETRAHEDRON = ((1.0, -1.0, -1.0), (-1.0, -1.0, 1.0), (-1.0, 1.0, -1.0), (1.0, 1.0, 1.0))
"""The offsets of :func:`tetrahedral_gradient`: a regular tetrahedron's corners, ``sum_k v_k v_k^T = 4 I``."""


def tetrahedral_gradient(function, p: torch.Tensor, step: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(f (N,), grad f (N, 3), features (N, C))`` at ``p`` (N, 3) from ``function`` at four points around each.

    ``function``: ``(M, 3) -> (f (M,), features (M, C))``, called once on the ``4 N`` points
    ``p + step v_k`` (``v_k`` the corners of :data:`TETRAHEDRON`). With ``f_k`` its values there,

        grad f ~ sum_k v_k f_k / (4 step),      f ~ mean_k f_k,      features ~ mean_k features_k

    (Taylor: ``sum_k v_k v_k^T = 4 I`` leaves the gradient, with an error ``step`` times the
    Hessian's off-diagonal terms; the mean is off by ``step^2 / 2`` times the Laplacian). Four
    evaluations where central differences take six, and none needs a gradient with respect to
    the points: the gradient is differentiable through ``function``'s parameters with ordinary
    backward passes (the SDF's eikonal term and its alphas' cosines), which ``torch.compile``'d
    kernels have, where autograd's gradient needs a double backward. The features are the mean
    over a region ``step`` wide: a blur below the finest hash cell at the default step.
    """
    offsets = step * torch.tensor(TETRAHEDRON, dtype=p.dtype, device=p.device)  # (4, 3)
    values, features = function((p[None] + offsets[:, None]).reshape(-1, 3))
    values, features = values.reshape(4, p.shape[0]), features.reshape(4, p.shape[0], features.shape[-1])
    gradient = torch.einsum("kn,kc->nc", values, offsets) / (4 * step * step)
    return values.mean(dim=0), gradient, features.mean(dim=0)


def first_of_ray(ray_indices: torch.Tensor) -> torch.Tensor:
    """``(N,)`` bool: the packed samples (sorted by ray) that are the first of their ray."""
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    return first


class SDFNetwork(nn.Module):
    """``p (N, 3)`` in ``[-1, 1]^3`` -> ``(f (N,), features (N, 15))``: the position and its hash encoding, an MLP.

    ``radius``: of the sphere the untrained network's zero level set is (geometric init, module
    docstring). Hash-grid options as :class:`~pointfield.fields.encodings.hashgrid.HashEncoding`.
    ``smooth``: softplus activations (NeuS's, whose second derivative autograd's eikonal term
    needs), else ReLU (instant-nsr-pl's and NeuS2's with numerical gradients; on a CPU a third
    of softplus's cost, which was 40 % of a finite-difference training step, measured).
    """

    def __init__(self, levels: int = 8, features_per_level: int = 4, log2_table_size: int = 17,
                 min_resolution: int = 16, max_resolution: int = 512, hidden: int = 64, radius: float = 0.5,
                 backend: str = "auto", smooth: bool = True):
        super().__init__()
        self.encoding = HashEncoding(levels, features_per_level, log2_table_size, min_resolution, max_resolution,
                                     backend=backend)
        self.first = nn.Linear(3 + self.encoding.output_dim, hidden)
        self.middle = nn.Linear(hidden, hidden)
        self.last = nn.Linear(hidden, 1 + GEOMETRY_FEATURES)
        self.activation = nn.Softplus(beta=SOFTPLUS_BETA) if smooth else nn.ReLU()
        self.geometric_init(radius)

    @torch.no_grad()
    def geometric_init(self, radius: float, fit_points: int = 8192) -> None:
        """SAL's initialisation (as NeuS's ``SDFNetwork``), then a fit: ``f(p) = |p| - radius`` at the start.

        Hidden layers ``W ~ N(0, 2 / fan_out)``, biases 0; the hash features' input weights 0
        (the sphere is the MLP's alone). SAL sets the distance row of the last layer to
        ``W ~ N(sqrt(pi / fan_in), 1e-4)``, bias ``-radius``, whose *expected* output is
        ``|p| - radius``; at 64 units wide one draw is a lumpy sphere (its zero level off by up
        to 0.2 of the box in places, measured). So that row is instead fitted by least squares
        (ridge 1e-3) to ``|p| - radius`` at ``fit_points`` seeded points of the box: the zero
        level then lies within about 0.015 of the sphere and ``|grad f|`` within 2 % of 1 near it.
        """
        for layer in (self.first, self.middle):
            nn.init.normal_(layer.weight, 0.0, math.sqrt(2) / math.sqrt(layer.out_features))
            nn.init.zeros_(layer.bias)
        self.first.weight[:, 3:] = 0.0
        nn.init.normal_(self.last.weight[:1], math.sqrt(math.pi) / math.sqrt(self.last.in_features), 1e-4)
        self.last.bias[:1] = -radius
        points = torch.rand((fit_points, 3), generator=torch.Generator().manual_seed(0)) * 2 - 1
        inputs = torch.cat([points, points.new_zeros(fit_points, self.first.in_features - 3)], dim=-1)
        hidden = self.activation(self.middle(self.activation(self.first(inputs))))
        design = torch.cat([hidden, hidden.new_ones(fit_points, 1)], dim=-1).double()
        target = (points.norm(dim=-1) - radius).double()
        ridge = 1e-3 * torch.eye(design.shape[1], dtype=torch.float64)
        solution = torch.linalg.solve(design.T @ design + ridge, design.T @ target)
        self.last.weight[0] = solution[:-1].to(self.last.weight.dtype)
        self.last.bias[0] = solution[-1].to(self.last.bias.dtype)

    def forward(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        features = self.encoding((p + 1) / 2)  # the encoding reads [0, 1]^3
        hidden = self.activation(self.first(torch.cat([p, features.to(p.dtype)], dim=-1)))
        out = self.last(self.activation(self.middle(hidden)))
        return out[..., 0], out[..., 1:]


class NeuralSDF(RadianceField):
    """The ``sdf`` model: :class:`SDFNetwork`, NeuS's alpha, an occupancy-grid marcher (module docstring).

    ``box``: ``(2, 3)`` world min/max of the object's box; ``unbounded`` must be False (an SDF of
    contracted space has no closed zero level set to export). ``steps_across_box``,
    ``grid_resolution``, ``target_samples``, the hash-grid options and ``backend`` as for
    :class:`~pointfield.fields.ngp.InstantNGP`; ``target_samples`` defaults to 2^13, an eighth
    of ngp's sample budget over a CPU's step: a sample here costs about three of ngp's with the
    finite-difference gradient (four evaluations) and four to five with autograd's (the eager
    hash grid, the gradient and its own backward): 0.067 and 0.107 ms a kept sample against
    ngp's 0.024, forward and backward through 1,024 rays of the untrained fields, one thread of a
    shared 2-core machine. With autograd's gradient on the cube at 64 px 2^13 gave
    128 steps and 21.1 dB in 60 s where 2^15 gave 34 steps and 19.6 dB (CUDA runs take
    :data:`~pointfield.fields.ngp.CUDA_OPTIONS`' 2^18). ``sphere_radius``: the untrained surface's
    radius as a fraction of the box's half-side; ``initial_variance``: ``v`` of ``s = exp(10 v)``;
    ``eikonal_weight`` and ``eikonal_points`` (uniform box points per step besides the samples).
    ``gradient``: "finite-difference" (default) or "autograd" (module docstring, step 3);
    ``finite_difference_step``: the tetrahedron's offset in box units (default half the finest
    hash cell, ``1 / max_resolution``). ``entry_outside``: rays come into the box from free space
    (module docstring, step 5); ``network_lr_fraction``: step 7 (1.0: one parameter group);
    ``sharpness_lr_fraction``: ``v``'s own rate, step 7; ``cos_anneal_steps``: step 5's anneal;
    ``min_weight``: the faint sections skipped, step 1 (0: none).
    """

    def __init__(
        self,
        box=((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5)),
        unbounded: bool = False,
        steps_across_box: int = 256,
        grid_resolution: int = 64,
        target_samples: int = 1 << 13,
        levels: int = 8,
        features_per_level: int = 4,
        log2_table_size: int = 17,
        min_resolution: int = 16,
        max_resolution: int = 512,
        hidden: int = 64,
        backend: str = "auto",
        sphere_radius: float = 0.5,
        initial_variance: float = INITIAL_VARIANCE,
        eikonal_weight: float = 0.1,
        eikonal_points: int = 1024,
        gradient: str = "finite-difference",
        finite_difference_step: float | None = None,
        entry_outside: bool = True,
        network_lr_fraction: float = NETWORK_LR_FRACTION,
        cos_anneal_steps: int = 0,
        min_weight: float = MIN_WEIGHT,
        sharpness_lr_fraction: float | None = None,
    ):
        super().__init__()
        if unbounded:
            raise ValueError("the sdf model needs a bounded scene (an object in a box); pass --scene-box bounded "
                             "or the box's six numbers")
        box = checked_box(box)
        if gradient not in GRADIENTS:
            raise ValueError(f"gradient is one of {', '.join(GRADIENTS)}; got {gradient!r}")
        if finite_difference_step is not None and not finite_difference_step > 0:
            raise ValueError(f"finite_difference_step must be > 0 (box units), got {finite_difference_step}")
        self.gradient = gradient
        self.entry_outside = bool(entry_outside)
        if not network_lr_fraction > 0:
            raise ValueError(f"network_lr_fraction must be > 0, got {network_lr_fraction}")
        self.network_lr_fraction = float(network_lr_fraction)
        if sharpness_lr_fraction is not None and not sharpness_lr_fraction > 0:
            raise ValueError(f"sharpness_lr_fraction must be > 0 (or None), got {sharpness_lr_fraction}")
        self.sharpness_lr_fraction = None if sharpness_lr_fraction is None else float(sharpness_lr_fraction)
        if cos_anneal_steps < 0:
            raise ValueError(f"cos_anneal_steps must be 0 (off) or more, got {cos_anneal_steps}")
        self.cos_anneal_steps = int(cos_anneal_steps)
        if not 0 <= min_weight < 1:
            raise ValueError(f"min_weight is a rendering weight in [0, 1), got {min_weight}")
        self.min_weight = float(min_weight)
        self._cos_anneal_ratio = 1.0  # before_step lowers it while annealing; renders of a trained field take 1
        self.finite_difference_step = (1.0 / max_resolution if finite_difference_step is None
                                       else float(finite_difference_step))
        if not 0 < sphere_radius < 1:
            raise ValueError(f"sphere_radius is a fraction of the box's half-side, in (0, 1); got {sphere_radius}")
        self.register_buffer("box", box.clone())
        self.register_buffer("centre", box.mean(dim=0))
        self.scale = 0.5 * float((box[1] - box[0]).max())  # world units per box unit
        self.backend = backend
        self.target_samples = int(target_samples)
        self.step_size = float(torch.linalg.norm(box[1] - box[0])) / float(steps_across_box)
        self.eikonal_weight, self.eikonal_points = float(eikonal_weight), int(eikonal_points)
        self.sdf = SDFNetwork(levels, features_per_level, log2_table_size, min_resolution, max_resolution, hidden,
                              sphere_radius, backend, smooth=gradient == "autograd")
        self.variance = nn.Parameter(torch.tensor(float(initial_variance)))
        direction_dim = (DIRECTION_SH_DEGREE + 1) ** 2
        self.color_mlp = nn.Sequential(
            nn.Linear(direction_dim + 3 + GEOMETRY_FEATURES, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, 3),
        )
        self.grid = OccupancyGrid(box, grid_resolution)
        # Half a cell's diagonal in box units: no point of a cell is nearer the surface than its
        # sampled point's |f| minus this, where |grad f| = 1.
        self._cell_margin = 0.5 * math.sqrt(3) * 2.0 / grid_resolution

    def parameter_groups(self, learning_rate: float) -> list[dict]:
        """Adam's parameter groups: the hash table at ``learning_rate``, the MLPs and ``v`` at ``network_lr_fraction`` of it.

        Adam moves every parameter by about its learning rate a step whatever its gradient, and
        the SDF network's last bias is a global offset of ``f``: at the hash grid's 1e-2 the
        whole level set drifts a hundredth of the box a step, past the faces to the box's walls
        (where the rays start inside the solid and NeuS's ratio no longer pins it). instant-nsr-pl
        and NeuS2 train their MLPs and ``v`` at a tenth of the grid's rate too.
        """
        if self.network_lr_fraction == 1.0:  # one group, as runs made before this option have in their checkpoints
            return [{"params": list(self.parameters()), "lr": learning_rate}]
        table = [self.sdf.encoding.table]
        if self.sharpness_lr_fraction is None:  # v with the MLPs, as runs made before its own rate have it
            others = [p for p in self.parameters() if all(p is not t for t in table)]
            return [{"params": table, "lr": learning_rate},
                    {"params": others, "lr": learning_rate * self.network_lr_fraction}]
        others = [p for p in self.parameters() if p is not self.variance and all(p is not t for t in table)]
        return [{"params": table, "lr": learning_rate},
                {"params": others, "lr": learning_rate * self.network_lr_fraction},
                {"params": [self.variance], "lr": learning_rate * self.sharpness_lr_fraction}]

    @property
    def extent(self) -> SceneExtent:
        """The box this field covers, which bounds every ray rendered through it."""
        return SceneExtent(self.box.tolist(), False)

    @property
    def sharpness(self) -> torch.Tensor:
        """``s = exp(10 v)``, in inverse box units (clamped to ``[1e-6, 1e6]``)."""
        return torch.exp(10 * self.variance).clamp(1e-6, 1e6)

    def to_box_units(self, positions: torch.Tensor) -> torch.Tensor:
        """World positions ``(..., 3)`` -> ``p = (x - c) / r``: the box inside ``[-1, 1]^3``."""
        return (positions - self.centre) / self.scale

    @torch.no_grad()
    def sdf_at(self, positions: torch.Tensor) -> torch.Tensor:
        """The signed distance ``(N,)`` at world ``positions`` ``(N, 3)``, in world units (no gradients)."""
        return self.scale * self.sdf(self.to_box_units(positions))[0]

    def sdf_and_gradient(self, p: torch.Tensor, create_graph: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(f (N,), grad f (N, 3), features (N, 15))`` at box-unit points ``p`` (N, 3).

        By :func:`tetrahedral_gradient` or autograd (``gradient``, module docstring, step 3).
        ``create_graph``: keep the gradient differentiable (training: the eikonal loss and the
        alphas' cosines backpropagate through it); else all three come back detached (rendering).
        """
        if self.gradient == "finite-difference":
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                f, gradient, features = tetrahedral_gradient(self.sdf, p.detach(), self.finite_difference_step)
            if not create_graph:
                f, gradient, features = f.detach(), gradient.detach(), features.detach()
            return f, gradient, features
        with torch.enable_grad():
            p = p.detach().requires_grad_(True)
            f, features = self.sdf(p)
            (gradient,) = torch.autograd.grad(f.sum(), p, create_graph=create_graph)
        if not create_graph:
            f, gradient, features = f.detach(), gradient.detach(), features.detach()
        return f, gradient, features

    def alphas(self, f: torch.Tensor, gradient: torch.Tensor, directions: torch.Tensor,
               deltas: torch.Tensor, first: torch.Tensor | None = None) -> torch.Tensor:
        """NeuS's section opacities ``(N,)`` (module docstring, step 5); ``f``, ``deltas`` in box units.

        ``first`` (N,) bool: the sections that begin a ray's march, where it comes in from the
        free space outside the box: their start's distance is taken as at least 0.
        """
        true_cos = (directions * gradient).sum(dim=-1)
        cos = torch.clamp(true_cos, max=0.0)  # only surfaces the ray enters
        r = self._cos_anneal_ratio
        if r < 1.0:  # NeuS's anneal: every section absorbs a little at first, whichever way it faces
            cos = -(F.relu(0.5 - 0.5 * true_cos) * (1 - r) + F.relu(-true_cos) * r)
        start = f - cos * deltas / 2
        if first is not None and self.entry_outside:
            start = torch.where(first, start.clamp(min=0.0), start)
        previous_cdf = torch.sigmoid(self.sharpness * start)
        next_cdf = torch.sigmoid(self.sharpness * (f + cos * deltas / 2))
        # NeuS's code adds its 1e-5 to the numerator too, which deep inside the solid (both CDFs
        # near 0) makes sections the ray leaves, or runs along, up to 1e-5 / Phi opaque.
        return ((previous_cdf - next_cdf) / (previous_cdf + 1e-5)).clamp(0.0, 1.0)

    # -- training hooks ---------------------------------------------------------------------------

    @torch.no_grad()
    def occupancy_density(self, positions: torch.Tensor) -> torch.Tensor:
        """``(N,)`` the largest logistic density ``s Phi_s(-u)(1 - Phi_s(-u))`` in each point's cell, per world unit.

        ``u = max(|f| - half a cell's diagonal, 0)``: the nearest the surface can be to any point
        of the cell, so a cell the surface crosses is always occupied; cells deep inside or
        outside are skipped.
        """
        f, _ = self.sdf(self.to_box_units(positions))
        nearest = (f.abs() - self._cell_margin).clamp(min=0)
        s = self.sharpness
        cdf = torch.sigmoid(-s * nearest)
        return s * cdf * (1 - cdf) / self.scale

    def before_step(self, step: int, generator: torch.Generator | None = None) -> None:
        """Before training step ``step``: refresh the occupancy grid from the SDF; advance the cosine anneal."""
        if self.cos_anneal_steps:
            self._cos_anneal_ratio = min(1.0, step / self.cos_anneal_steps)
        self.grid.update(self.occupancy_density, step, self.step_size, generator)

    def warm_up(self, rays: int = 1024) -> None:
        """Run the marcher and the SDF once, with and without gradients, so their compiled kernels are built off the clock."""
        device = self.box.device
        generator = torch.Generator().manual_seed(0)
        directions = F.normalize(torch.randn((rays, 3), generator=generator), dim=-1).to(device)
        radius = float(torch.linalg.norm(self.box[1] - self.box[0]))
        origins = self.centre - radius * directions
        bundle = RayBundle(origins, directions, torch.zeros(rays, device=device), torch.full((rays,), 2 * radius,
                                                                                             device=device))
        with torch.no_grad():
            samples = march_rays(bundle, self.grid, self.step_size, backend=self.backend)
            self.sdf(self.to_box_units(samples.positions(bundle)))
        if self.gradient == "finite-difference":  # training's pass: the hash grid's compiled backward
            self.sdf(self.to_box_units(samples.positions(bundle)))[0].sum().backward()
        self.zero_grad(set_to_none=True)

    # -- rendering ----------------------------------------------------------------------------------

    @torch.no_grad()
    def terminated(self, samples: RaySamples, rays: RayBundle) -> tuple[RaySamples, torch.Tensor]:
        """The packed ``samples`` worth the full field, and which of them begin their ray's march ``(S',)`` bool.

        Kept: those before each ray's estimated transmittance falls below
        ``EARLY_STOP_TRANSMITTANCE`` whose estimated weight ``T_i alpha_i`` is over ``min_weight``.
        One gradient-free evaluation of ``f`` per sample; section ``i`` of a ray, up to its next
        sample, has opacity ``1 - Phi_s(f_{i+1}) / Phi_s(f_i)`` (at least 0; NeuS's estimate when
        it up-samples, which needs no normal), its last section none. Dropping what lies behind
        changes no pixel by more than that transmittance; dropping the faint sections in front
        (free space in the surface's logistic tail) changes none by more than their weights.
        The march's first samples are marked before any is dropped (the entry rule, step 5).
        """
        first = first_of_ray(samples.ray_indices)
        if len(samples) < 2:
            return samples, first
        f = self.sdf(self.to_box_units(samples.positions(rays)))[0]
        cdf = torch.sigmoid(self.sharpness * f)
        if self.entry_outside:
            cdf = torch.where(first, cdf.clamp(min=0.5), cdf)
        same_ray = samples.ray_indices[1:] == samples.ray_indices[:-1]
        following = torch.cat([torch.where(same_ray, cdf[1:], cdf[:-1]), cdf[-1:]])
        alpha = (1 - following / (cdf + 1e-5)).clamp(0.0, MAX_ALPHA)
        transmittance = transmittance_from_optical_depth(-torch.log1p(-alpha), samples.ray_indices)
        keep = transmittance > EARLY_STOP_TRANSMITTANCE
        if self.min_weight > 0:
            keep &= transmittance * alpha > self.min_weight
        return samples.select(keep), first[keep]

    def forward(
        self,
        rays: RayBundle,
        background: torch.Tensor | None = None,
        jitter: bool = False,
        generator: torch.Generator | None = None,
    ) -> FieldOutput:
        """Render ``rays``: one pass; while training with gradients, the eikonal loss as the auxiliary loss."""
        training = torch.is_grad_enabled() and self.training
        samples = march_rays(rays, self.grid, self.step_size, jitter, generator, self.backend)
        probed = len(samples)
        samples, first = self.terminated(samples, rays)
        directions = samples.view_directions(rays)
        f, gradient, features = self.sdf_and_gradient(self.to_box_units(samples.positions(rays)), training)
        alpha = self.alphas(f, gradient, directions, samples.deltas / self.scale, first)
        sigmas = -torch.log1p(-alpha.clamp(max=MAX_ALPHA)) / samples.deltas.clamp_min(1e-10)
        normals = F.normalize(gradient, dim=-1)
        view = sh_basis(directions, DIRECTION_SH_DEGREE)
        colors = torch.sigmoid(self.color_mlp(torch.cat([view, normals, features], dim=-1)))
        rendered = composite(sigmas, colors, samples, background)
        cost = float(len(samples)) + PROBE_COST * probed
        auxiliary = None
        if training and self.eikonal_weight > 0:
            uniform = torch.rand((self.eikonal_points, 3), generator=generator).to(rays.device) * 2 - 1
            _, uniform_gradient, _ = self.sdf_and_gradient(uniform, True)
            norms = torch.linalg.norm(torch.cat([gradient, uniform_gradient]), dim=-1)
            auxiliary = self.eikonal_weight * ((norms - 1) ** 2).mean()
            cost += PROBE_COST * self.eikonal_points
        return FieldOutput([rendered], auxiliary, cost)
