"""Densification and pruning: how the set of splats grows and shrinks while training.

A strategy is an object with two methods that training calls around every step; swap in
another object to change the policy (gsplat's design):

- ``after_backward(gaussians, optimizer, meta, step, width, height)`` once the gradients of
  a step exist (``meta`` is :func:`~pointfield.splats.rasterizer.rasterization`'s, with
  ``meta["means2d"].retain_grad()`` called before ``backward``): gather statistics, and every
  so often add, remove or reset splats, resizing the optimizer's state to match;
- ``sh_degree_at(step)``: the SH degree rendering should use at ``step``;
- ``regularization(gaussians)``: a term training adds to the loss (0 when the policy has none).

:class:`DefaultStrategy` is the policy of the 3D Gaussian splatting paper, with gsplat's
names and defaults; :class:`MCMCStrategy` is 3DGS-MCMC's (Kheradmand et al. 2024, gsplat's
``MCMCStrategy``). :func:`make_strategy` is the one place a name (``--strategy``) becomes one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from pointfield.splats.gaussians import PARAMETER_NAMES, Gaussians, covariances, quaternion_to_rotation

STRATEGIES = ("default", "mcmc")


@dataclass
class DefaultStrategy:
    """Clone, split, prune and reset opacity as 3DGS does; cap the splat count.

    Every ``refine_every`` steps from ``refine_start`` until ``refine_stop``:

    - the average screen-space gradient norm of each splat's 2D mean since the last refinement
      (gradients scaled to normalised device coordinates, ``x (W/2, H/2)``, as in gsplat) is
      compared with ``grad_threshold``; splats above it are **cloned** (copied in place) when
      small (largest scale <= ``grow_scale3d`` x ``scene_scale``) and **split** when large
      (replaced by two splats drawn from the Gaussian, scales divided by 1.6);
    - splats with opacity below ``prune_opacity`` are **pruned**, and after the first opacity
      reset also those larger than ``prune_scale3d`` x ``scene_scale``.

    Every ``reset_every`` steps all opacities are clamped to at most ``reset_opacity``, which
    lets the optimisation decide again which splats matter. The SH degree rises by one every
    ``sh_degree_interval`` steps up to the model's. Growth stops at ``max_splats``: the splats
    with the largest gradients are grown first, and a message (``log``) says once that the cap
    was reached.
    """

    scene_scale: float = 1.0
    grad_threshold: float = 0.0002
    grow_scale3d: float = 0.01
    prune_opacity: float = 0.005
    prune_scale3d: float = 0.1
    refine_start: int = 500
    refine_stop: int = 15_000
    refine_every: int = 100
    reset_every: int = 3000
    reset_opacity: float = 0.01
    sh_degree_interval: int = 1000
    max_splats: int = 1_000_000
    seed: int = 0
    log: Callable[[str], None] = print
    grad_sum: torch.Tensor | None = field(default=None, repr=False)
    visible_count: torch.Tensor | None = field(default=None, repr=False)
    cap_reported: bool = field(default=False, repr=False)

    def sh_degree_at(self, step: int, max_degree: int) -> int:
        return min(max_degree, step // self.sh_degree_interval)

    def regularization(self, gaussians: Gaussians) -> torch.Tensor | float:
        return 0.0

    def after_backward(
        self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, meta: dict, step: int,
        width: int, height: int,
    ) -> dict[str, int]:
        """Update statistics with this step's gradients; refine when due. Returns what changed."""
        changes = {"cloned": 0, "split": 0, "pruned": 0}
        if step >= self.refine_stop:
            return changes
        self._accumulate(gaussians, meta, width, height)
        if step > self.refine_start and step % self.refine_every == 0:
            changes.update(self._grow(gaussians, optimizer, step))
            changes["pruned"] = self._prune(gaussians, optimizer, step)
            self.grad_sum = self.visible_count = None
        if step > 0 and step % self.reset_every == 0:
            self._reset_opacity(gaussians, optimizer)
        return changes

    # -- statistics --------------------------------------------------------------------------

    def _accumulate(self, gaussians: Gaussians, meta: dict, width: int, height: int) -> None:
        means2d = meta["means2d"]
        if means2d.grad is None:
            return
        count = len(gaussians)
        if self.grad_sum is None or len(self.grad_sum) != count:
            self.grad_sum = torch.zeros(count, device=gaussians.means.device)
            self.visible_count = torch.zeros(count, device=gaussians.means.device)
        cameras = means2d.shape[0]
        scale = torch.tensor([width / 2 * cameras, height / 2 * cameras], device=means2d.device)
        norms = (means2d.grad.detach() * scale.to(means2d.dtype)).norm(dim=-1)   # (C, N)
        visible = meta["radii"] > 0
        self.grad_sum += torch.where(visible, norms, torch.zeros_like(norms)).sum(0).float()
        self.visible_count += visible.sum(0).float()

    # -- growing -----------------------------------------------------------------------------

    def _grow(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, step: int) -> dict[str, int]:
        if self.grad_sum is None:
            return {"cloned": 0, "split": 0}
        average = self.grad_sum / self.visible_count.clamp_min(1)
        high = average > self.grad_threshold
        room = self.max_splats - len(gaussians)
        wanted = int(high.sum())
        # Each clone or split adds one splat; keep the largest gradients within the cap.
        if wanted > room:
            if not self.cap_reported:
                self.log(
                    f"splat cap of {self.max_splats:,} reached at step {step}: densification "
                    f"wanted {wanted:,} more splats and is now limited to the cap (raise "
                    f"--max-splats to allow more)"
                )
                self.cap_reported = True
            keep = torch.zeros_like(high)
            if room > 0:
                keep[torch.topk(torch.where(high, average, torch.zeros_like(average)), room).indices] = True
            high = high & keep
        small = gaussians.scales.detach().max(dim=1).values <= self.grow_scale3d * self.scene_scale
        clone = high & small
        split = high & ~small
        with torch.no_grad():
            if clone.any():
                new = {name: getattr(gaussians, name).detach()[clone] for name in PARAMETER_NAMES}
                append_splats(gaussians, optimizer, new)
            if split.any():
                # The clones were appended after the originals: they are not split.
                not_split = torch.zeros(int(clone.sum()), dtype=torch.bool, device=split.device)
                self._split(gaussians, optimizer, torch.cat([split, not_split]))
        return {"cloned": int(clone.sum()), "split": int(split.sum())}

    def _split(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, split: torch.Tensor) -> None:
        """Replace each splat in ``split`` by two drawn from it, 1.6 times smaller (3DGS)."""
        generator = torch.Generator(device="cpu").manual_seed(self.seed + len(gaussians))
        scales = gaussians.scales.detach()[split]
        rotations = quaternion_to_rotation(gaussians.quats.detach()[split])
        offsets = torch.randn(2, *scales.shape, generator=generator, dtype=scales.dtype).to(scales.device) * scales
        centres = gaussians.means.detach()[split]
        new = {}
        for name in PARAMETER_NAMES:
            value = getattr(gaussians, name).detach()[split]
            new[name] = torch.cat([value, value])
        new["means"] = torch.cat([centres + (rotations @ offsets[i][..., None])[..., 0] for i in range(2)])
        new["log_scales"] = torch.log(scales / 1.6).repeat(2, 1)
        remove_splats(gaussians, optimizer, ~split)
        append_splats(gaussians, optimizer, new)

    # -- pruning and resetting ---------------------------------------------------------------

    def _prune(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, step: int) -> int:
        with torch.no_grad():
            doomed = gaussians.opacities < self.prune_opacity
            if step > self.reset_every:
                doomed |= gaussians.scales.max(dim=1).values > self.prune_scale3d * self.scene_scale
            # Never prune every splat: an empty model cannot recover.
            if doomed.all():
                return 0
            if doomed.any():
                remove_splats(gaussians, optimizer, ~doomed)
        return int(doomed.sum())

    def _reset_opacity(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer) -> None:
        limit = math.log(self.reset_opacity / (1 - self.reset_opacity))
        with torch.no_grad():
            gaussians.opacity_logits.data.clamp_(max=limit)
        state = optimizer.state.get(gaussians.opacity_logits, {})
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key].zero_()


@dataclass
class MCMCStrategy:
    """3DGS-MCMC's densification (Kheradmand et al., "3D Gaussian Splatting as Markov Chain Monte
    Carlo", 2024), with the names and defaults of gsplat's ``MCMCStrategy``.

    The splats are samples of a distribution, and densification is moving samples, never
    cloning by a gradient threshold. Every ``refine_every`` steps from ``refine_start`` until
    ``refine_stop``:

    - **relocate**: every dead splat (opacity <= ``min_opacity``) is moved onto a live one drawn
      with probability proportional to opacity (with replacement); a splat drawn ``n - 1``
      times is shared by ``n`` copies, each given the paper's opacity and scale (Eq. 9) so
      that together they render as the one did::

          o' = 1 - (1 - o)^(1/n)
          s' = o / (sum_{i=1}^{n} sum_{k=0}^{i-1} C(i-1, k) (-1)^k o'^(k+1) / sqrt(k+1)) * s

      (``n`` at most ``max_ratio``), and the Adam moments of the splats involved restart at 0;
    - **add**: ``growth - 1`` (5 %) more splats, drawn the same way, up to ``max_splats``: a
      hard cap, which the count reaches and keeps.

    After every step each mean moves by noise ``lr * noise_lr * Sigma eps`` (``eps`` standard
    normal, ``Sigma`` the splat's covariance, ``lr`` the means' current learning rate), gated
    by ``sigmoid(100 (1 - o - 0.995))`` so that only nearly transparent splats wander: the
    exploration of the MCMC sampler, which makes it robust to a random start.
    :meth:`regularization` is the paper's ``opacity_reg * mean(o) + scale_reg * mean(s)``
    (scales in units of ``scene_scale``: gsplat's scenes are normalised to about unit size,
    pointfield's are not), which lets unneeded splats die and be relocated.
    """

    scene_scale: float = 1.0
    max_splats: int = 1_000_000
    refine_start: int = 500
    refine_stop: int = 25_000
    refine_every: int = 100
    min_opacity: float = 0.005
    growth: float = 1.05
    noise_lr: float = 5e5
    opacity_reg: float = 0.01
    scale_reg: float = 0.01
    max_ratio: int = 51
    sh_degree_interval: int = 1000
    seed: int = 0
    log: Callable[[str], None] = print

    def sh_degree_at(self, step: int, max_degree: int) -> int:
        return min(max_degree, step // self.sh_degree_interval)

    def regularization(self, gaussians: Gaussians) -> torch.Tensor:
        return (self.opacity_reg * gaussians.opacities.mean()
                + self.scale_reg * gaussians.scales.mean() / self.scene_scale)

    def after_backward(
        self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, meta: dict, step: int,
        width: int, height: int,
    ) -> dict[str, int]:
        """Relocate and add when due, then move the means by the noise. Returns what changed."""
        changes = {"relocated": 0, "added": 0}
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + step)
        if self.refine_start < step < self.refine_stop and step % self.refine_every == 0:
            changes["relocated"] = self._relocate(gaussians, optimizer, generator)
            changes["added"] = self._add(gaussians, optimizer, generator)
        self._add_noise(gaussians, optimizer, generator)
        return changes

    def _relocate(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, generator: torch.Generator) -> int:
        opacities = gaussians.opacities.detach()
        dead = opacities <= self.min_opacity
        count = int(dead.sum())
        if count == 0 or bool(dead.all()):  # nothing to move, or nowhere to move it
            return 0
        alive = torch.nonzero(~dead).squeeze(1)
        sampled = alive[_draw(opacities[alive], count, generator)]
        self._share(gaussians, optimizer, sampled)
        dead_ids = torch.nonzero(dead).squeeze(1)
        with torch.no_grad():
            for name in PARAMETER_NAMES:
                getattr(gaussians, name)[dead_ids] = getattr(gaussians, name)[sampled]
        _restart_moments(gaussians, optimizer, dead_ids)
        return count

    def _add(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, generator: torch.Generator) -> int:
        current = len(gaussians)
        count = min(self.max_splats, int(self.growth * current)) - current
        if count <= 0:
            return 0
        sampled = _draw(gaussians.opacities.detach(), count, generator)
        self._share(gaussians, optimizer, sampled)
        append_splats(gaussians, optimizer, {name: getattr(gaussians, name).detach()[sampled]
                                             for name in PARAMETER_NAMES})
        return count

    def _share(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, sampled: torch.Tensor) -> None:
        """Give each splat drawn ``n - 1`` times the opacity and scale of one of ``n`` copies (Eq. 9)."""
        ratios = torch.bincount(sampled, minlength=len(gaussians))[sampled] + 1
        opacities, scales = relocation(gaussians.opacities.detach()[sampled], gaussians.scales.detach()[sampled],
                                       ratios, self.max_ratio)
        opacities = opacities.clamp(self.min_opacity, 1 - torch.finfo(opacities.dtype).eps)
        with torch.no_grad():
            gaussians.opacity_logits[sampled] = torch.logit(opacities)
            gaussians.log_scales[sampled] = torch.log(scales)
        _restart_moments(gaussians, optimizer, sampled)

    def _add_noise(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer, generator: torch.Generator) -> None:
        learning_rate = next((group["lr"] for group in optimizer.param_groups
                              if any(p is gaussians.means for p in group["params"])), 0.0)
        with torch.no_grad():
            opacities = gaussians.opacities
            gate = torch.sigmoid(100 * ((1 - opacities) - 0.995))
            noise = torch.randn(len(gaussians), 3, generator=generator, dtype=opacities.dtype).to(opacities.device)
            noise = noise * (gate * learning_rate * self.noise_lr)[:, None]
            gaussians.means += (covariances(gaussians.quats, gaussians.scales) @ noise[..., None])[..., 0]


def relocation(opacities: torch.Tensor, scales: torch.Tensor, ratios: torch.Tensor,
               max_ratio: int = 51) -> tuple[torch.Tensor, torch.Tensor]:
    """3DGS-MCMC's Eq. 9: the opacity ``(M,)`` and scales ``(M, 3)`` of each of ``ratios`` ``(M,)``
    copies of a splat that together render like it (see :class:`MCMCStrategy`).

    The alternating double sum is evaluated in float64 (its binomials reach 1e14 at ``n = 51``),
    with ``n`` clamped to ``max_ratio`` as gsplat does.
    """
    dtype = opacities.dtype
    n = ratios.clamp(1, max_ratio).to(torch.float64)
    o = opacities.to(torch.float64)
    shared = 1 - (1 - o) ** (1 / n)
    k = torch.arange(max_ratio, dtype=torch.float64, device=o.device)
    binomials = torch.tensor([[math.comb(i, j) for j in range(max_ratio)] for i in range(max_ratio)],
                             dtype=torch.float64, device=o.device)       # (i - 1, k), 0 for k > i - 1
    terms = binomials * ((-1.0) ** k / torch.sqrt(k + 1))                # (I, K)
    inner = (shared[:, None] ** (k + 1)) @ terms.T                       # (M, I): the sum over k for each i
    used = torch.arange(1, max_ratio + 1, device=o.device)[None, :] <= n[:, None]
    denominator = (inner * used).sum(1)
    return shared.to(dtype), ((o / denominator)[:, None] * scales.to(torch.float64)).to(dtype)


def _draw(weights: torch.Tensor, count: int, generator: torch.Generator) -> torch.Tensor:
    """``count`` indices drawn with replacement, with probability proportional to ``weights`` (N,)."""
    drawn = torch.multinomial(weights.detach().float().cpu().clamp_min(0), count, replacement=True,
                              generator=generator)
    return drawn.to(weights.device)


def _restart_moments(gaussians: Gaussians, optimizer: torch.optim.Optimizer, index: torch.Tensor) -> None:
    """Zero the Adam moments of the splats ``index`` in every parameter (their values were replaced)."""
    for name in PARAMETER_NAMES:
        state = optimizer.state.get(getattr(gaussians, name), {})
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key][index] = 0


def make_strategy(name: str, *, scene_scale: float, max_splats: int, seed: int, steps: int,
                  log: Callable[[str], None] = print) -> DefaultStrategy | MCMCStrategy:
    """The densification strategy ``name`` (``STRATEGIES``) with its schedule scaled to a run of ``steps``.

    Both start refining at step 500 or a tenth of the run, whichever is first, and raise the
    SH degree every 1000 steps or a quarter of the run; the default strategy stops at half the
    run (3DGS: 15,000 of 30,000 steps), MCMC at five sixths (gsplat: 25,000 of 30,000).
    """
    common = {"scene_scale": scene_scale, "max_splats": max_splats, "seed": seed, "log": log,
              "refine_start": min(500, steps // 10), "sh_degree_interval": max(min(1000, steps // 4), 1)}
    if name == "default":
        return DefaultStrategy(refine_stop=max(steps // 2, 1), **common)
    if name == "mcmc":
        return MCMCStrategy(refine_stop=max(steps * 5 // 6, 1), **common)
    raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}, got {name!r}")


def remove_splats(gaussians: Gaussians, optimizer: torch.optim.Optimizer, keep: torch.Tensor) -> None:
    """Keep only the splats where ``keep`` (N,) is true, in the model and the optimizer's state."""
    for name in PARAMETER_NAMES:
        replace_parameter(gaussians, optimizer, name, lambda value: value[keep])


def append_splats(gaussians: Gaussians, optimizer: torch.optim.Optimizer, new: dict[str, torch.Tensor]) -> None:
    """Add splats (``new``: a value per parameter name); their optimizer moments start at zero."""
    for name in PARAMETER_NAMES:
        addition = new[name]
        replace_parameter(
            gaussians, optimizer, name,
            lambda value, addition=addition: torch.cat([value, torch.zeros_like(addition, dtype=value.dtype)]),
            torch.cat([getattr(gaussians, name).detach(), addition.to(getattr(gaussians, name).dtype)]),
        )


def replace_parameter(
    gaussians: Gaussians, optimizer: torch.optim.Optimizer, name: str, edit, value: torch.Tensor | None = None,
) -> None:
    """Swap parameter ``name`` for a new one of another length, and edit its Adam moments alike.

    ``edit`` maps an ``(N, ...)`` tensor to the new ``(M, ...)`` one; it is applied to the
    parameter (unless ``value`` is given) and to ``exp_avg`` / ``exp_avg_sq``. A new Parameter
    object is needed: autograd remembers each leaf's shape, so resizing ``.data`` in place
    breaks the next backward pass.
    """
    old = getattr(gaussians, name)
    replacement = torch.nn.Parameter(edit(old.detach()) if value is None else value)
    for group in optimizer.param_groups:
        group["params"] = [replacement if p is old else p for p in group["params"]]
    state = optimizer.state.pop(old, None)
    if state is not None:
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key] = edit(state[key])
        optimizer.state[replacement] = state
    setattr(gaussians, name, replacement)
