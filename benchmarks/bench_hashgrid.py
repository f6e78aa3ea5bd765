"""Hash-grid throughput and Instant-NGP memory (issue 6).

(a) **Throughput**: forward + backward of the multiresolution hash encoding in samples per second,
for each implementation in :mod:`pointfield.fields.encodings.hashgrid` -- ``compiled`` (torch.compile),
``eager`` (hand-written backward) and ``reference_hash_encoding`` -- beside TinyNeRF's dense MLP
field (``RadianceMLP(depth=4, width=128, skips=(), color_width=64)`` on the same points, with
random view directions) and the whole :class:`~pointfield.fields.ngp.NGPField` (encoding + density
and colour MLPs). Each is timed as the median of ``--repeats`` calls after a first call whose time
is reported on its own (for ``compiled`` it includes compilation; torch caches compiled kernels
on disk, so a second run of the benchmark compiles faster); the forward pass alone (without
gradients) is timed likewise. Also timed: one Adam step over the field's parameters, which
moves every table entry every step.

(b) **Memory**: the parameter count of :class:`~pointfield.fields.ngp.InstantNGP`, and the peak
resident memory (``VmHWM`` on Linux, else ``ru_maxrss``; on CUDA also
``torch.cuda.max_memory_allocated``) of training it, each image size in a fresh subprocess,
mirroring ``pointfield nerf train``: the rays of every training view in memory (``scene_rays``;
90 views as lego with ``--holdout-every 10``), ``--memory-steps`` training steps whose ray count
adapts to ``InstantNGP.target_samples`` samples per step (occupancy grid, early termination,
Adam), then a held-out view rendered in ``RENDER_CHUNK``-ray chunks as the evaluation does -- at
100 x 100 all of it, at 800 x 800 the first ``--render-chunks`` chunks (through the middle of the
view, where rays cross the most of the box; every chunk costs about the same memory, and the
whole view takes many minutes on a CPU). The model is untrained -- the worst case: the occupancy
grid has seen one update (half its cells stay occupied), no ray terminates early. The scene is synthetic: NeRF-synthetic
cameras (4 units from the origin, lego's field of view) and blank images, since memory does not
depend on the pixels. The peak is reported after each phase, so one sees which phase set it.

Configurations: ``lego`` -- what ``pointfield nerf train lego --model ngp`` builds: the defaults
of ``InstantNGP`` with ``max_resolution`` set from the image size (twice its side: 200 for the
100 x 100 lego benchmark the throughput is measured for, 1600 at 800 x 800), or what
``--levels/--features/--log2-table/--max-resolution`` say -- and ``paper`` (Müller et al. 2022:
16 levels, F = 2, 2^19 entries, N_max 2048); listed once when they are the same.

Every implementation is timed against the others in the same run, interleaved (harness.py); the
record goes to ``benchmarks/records/hashgrid.json``.

Run: ``make bench-hashgrid`` (= ``.venv/bin/python benchmarks/bench_hashgrid.py``), a few minutes
on 2 cores; shorter: ``--points 16384 --repeats 2 --memory-steps 2 --render-chunks 1``, or
``--skip-memory`` / ``--skip-compiled``.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable

import torch

from harness import Record, device_name, interleaved

PAPER = {"levels": 16, "features_per_level": 2, "log2_table_size": 19, "max_resolution": 2048}
TRAINING_VIEWS = 90  # lego at --holdout-every 10
BOX = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))  # lego's box is about +-1.6
TARGET_GB = 24.0
THROUGHPUT_SIZE = 100  # the lego benchmark's image size


def lego_config(args: argparse.Namespace, size: int) -> dict[str, int]:
    """What ``pointfield nerf train lego --model ngp`` builds for ``size``-pixel views, or the command line's.

    InstantNGP's constructor defaults, with ``max_resolution`` from the image size as the training
    command sets it (:func:`pointfield.fields.scene_box.default_max_resolution`).
    """
    from types import SimpleNamespace

    from pointfield.fields.ngp import InstantNGP
    from pointfield.fields.scene_box import default_max_resolution

    defaults = {name: parameter.default for name, parameter in inspect.signature(InstantNGP).parameters.items()}
    side = torch.tensor([size])
    views = SimpleNamespace(cameras=SimpleNamespace(width=side, height=side))
    defaults["max_resolution"] = default_max_resolution(views, unbounded=False)
    chosen = {
        "levels": args.levels, "features_per_level": args.features,
        "log2_table_size": args.log2_table, "max_resolution": args.max_resolution,
    }
    return {name: int(defaults[name] if value is None else value) for name, value in chosen.items()}


def configurations(args: argparse.Namespace) -> dict[str, Callable[[int], dict[str, int]]]:
    """Name -> the configuration for an image size; "lego" is left out where it is the paper's."""
    configs = {"lego": lambda size: lego_config(args, size), "paper": lambda size: dict(PAPER)}
    if all(lego_config(args, size) == PAPER for size in (100, *args.sizes)):
        return {"lego = paper": configs["paper"]}
    return configs


def describe(config: dict[str, int]) -> str:
    return (f"L={config['levels']} F={config['features_per_level']} T=2^{config['log2_table_size']} "
            f"N_max={config['max_resolution']}")


# -- (a) throughput -----------------------------------------------------------------------------------


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def first_call_seconds(run, device: torch.device) -> float:
    """Seconds of one call (the first: for ``compiled`` it includes compilation)."""
    synchronize(device)
    started = time.perf_counter()
    run()
    synchronize(device)
    return time.perf_counter() - started


def encoding_calls(encoding, encode, points, upstream):
    """``(forward, forward + backward)`` of ``encode(encoding, points)``, the latter into the table's gradient."""

    def forward():
        with torch.no_grad():
            encode(encoding, points)

    def forward_backward():
        encoding.table.grad = None
        (encode(encoding, points) * upstream).sum().backward()

    return forward, forward_backward


def field_calls(field, points, directions):
    """``(forward, forward + backward)`` of a radiance field ``(x, d) -> (sigma, rgb)``, into its parameters."""

    def forward():
        with torch.no_grad():
            field(points, directions)

    def forward_backward():
        field.zero_grad(set_to_none=True)
        sigma, rgb = field(points, directions)
        (sigma.sum() + rgb.sum()).backward()

    return forward, forward_backward


def adam_step_seconds(config: dict[str, int], args: argparse.Namespace, device: torch.device) -> dict[str, float]:
    """Median seconds of one Adam step over an NGPField's parameters (dense: every table entry moves)."""
    from pointfield.fields.ngp import NGPField

    field = NGPField(**config, backend="eager").to(device)
    for parameter in field.parameters():
        parameter.grad = torch.randn_like(parameter)
    steps = {name: torch.optim.Adam(field.parameters(), lr=1e-2, betas=(0.9, 0.99), eps=1e-15, **options).step
             for name, options in (("default", {}), ("fused", {"fused": True}))}
    timings = interleaved(steps, args.repeats, synchronize=lambda: synchronize(device))
    return {name: timing.median for name, timing in timings.items()}


def throughput(config: dict[str, int], args: argparse.Namespace, device: torch.device) -> list[dict]:
    """One row per implementation: first call, then medians of interleaved forward + backward and forward calls."""
    from pointfield.compiling import compiler_available
    from pointfield.fields.encodings.hashgrid import HashEncoding, reference_hash_encoding
    from pointfield.fields.nerf import RadianceMLP
    from pointfield.fields.ngp import NGPField

    generator = torch.Generator().manual_seed(0)
    points = torch.rand(args.points, 3, generator=generator).to(device)
    directions = torch.nn.functional.normalize(torch.randn(args.points, 3, generator=generator), dim=-1).to(device)
    upstream = torch.randn(args.points, config["levels"] * config["features_per_level"], generator=generator).to(device)
    backends = ["eager"] if args.skip_compiled or not compiler_available(device) else ["compiled", "eager"]
    contenders = {}  # name -> (forward, forward + backward)
    for backend in backends:
        encoding = HashEncoding(**config, backend=backend).to(device)
        contenders[f"hash encoding, {backend}"] = encoding_calls(encoding, lambda e, x: e(x), points, upstream)
    encoding = HashEncoding(**config, backend="eager").to(device)
    contenders["hash encoding, reference"] = encoding_calls(encoding, reference_hash_encoding, points, upstream)
    contenders["TinyNeRF MLP field"] = field_calls(
        RadianceMLP(depth=4, width=128, skips=(), color_width=64).to(device), points, directions)
    for backend in backends:
        contenders[f"NGPField, {backend}"] = field_calls(NGPField(**config, backend=backend).to(device), points, directions)

    first = {name: first_call_seconds(calls[1], device) for name, calls in contenders.items()}
    wait = lambda: synchronize(device)  # noqa: E731
    both = interleaved({name: calls[1] for name, calls in contenders.items()}, args.repeats, warmup=0, synchronize=wait)
    forward = interleaved({name: calls[0] for name, calls in contenders.items()}, args.repeats, synchronize=wait)
    return [{"implementation": name, "first_s": first[name], "median_s": both[name].median, "spread": both[name].spread,
             "forward_s": forward[name].median, "samples_per_s": args.points / both[name].median}
            for name in contenders]


def throughput_table(record: Record, name: str, config: dict[str, int], rows: list[dict], points: int) -> None:
    reference = next(r for r in rows if r["implementation"] == "hash encoding, reference")
    mlp = next(r for r in rows if r["implementation"] == "TinyNeRF MLP field")
    record.table(
        ["implementation", "first s", "median s", "spread", "samples/s", "x reference", "x TinyNeRF MLP", "forward s"],
        [[row["implementation"], f"{row['first_s']:.2f}", f"{row['median_s']:.4f}", f"{row['spread']:.0%}",
          f"{row['samples_per_s']:.3g}", f"{row['samples_per_s'] / reference['samples_per_s']:.2f}",
          f"{row['samples_per_s'] / mlp['samples_per_s']:.2f}", f"{row['forward_s']:.4f}"] for row in rows],
        title=f"throughput, {name} ({describe(config)}), {points:,} samples, forward + backward unless said; "
              f"median of {len(rows)} implementations interleaved",
    )


# -- (b) memory -----------------------------------------------------------------------------------------


def parameter_counts(config: dict[str, int]) -> dict[str, int]:
    from pointfield.fields.ngp import InstantNGP

    counts = {}
    for unbounded in (False, True):
        model = InstantNGP(BOX, unbounded=unbounded, backend="eager", **config)
        counts["unbounded" if unbounded else "bounded"] = sum(p.numel() for p in model.parameters())
        counts["hash table" if not unbounded else "proposal networks"] = (
            model.field.encoding.table.numel() if not unbounded else sum(p.numel() for p in model.proposal.parameters())
        )
    return counts


def proc_status_mb(field: str) -> float | None:
    """``VmHWM`` (peak) or ``VmRSS`` (now) of /proc/self/status in MB; None off Linux."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024  # kB
    except OSError:
        pass
    return None


def peak_mb() -> float:
    """This process's peak resident memory so far, MB.

    Linux: ``VmHWM``, which starts afresh at ``exec`` -- unlike ``ru_maxrss``, which a subprocess
    inherits from the parent it was forked from. Elsewhere ``ru_maxrss``.
    """
    peak = proc_status_mb("VmHWM")
    if peak is not None:
        return peak
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024  # macOS: bytes, others: KiB


def memory_child(request: dict) -> dict:
    """One configuration and image size, in this (fresh) process: see the module docstring (b)."""
    import numpy as np

    from pointfield.devices import pick_device
    from pointfield.fields.field import RayBudget, render_in_chunks
    from pointfield.fields.ngp import InstantNGP
    from pointfield.fields.run import RENDER_CHUNK
    from pointfield.fields.train import scene_rays
    from pointfield.scenes import Frame, Scene
    from pointfield.scenes.synthetic import synthetic_cameras

    device = pick_device(request["device"])
    size, views = request["size"], request["views"]
    phases = {"python + torch": (peak_mb(), proc_status_mb("VmRSS"))}

    def mark(phase):
        synchronize(device)
        phases[phase] = (peak_mb(), proc_status_mb("VmRSS"))
        if device.type == "cuda":
            phases[phase + " (cuda)"] = (torch.cuda.max_memory_allocated(device) / 2**20,
                                         torch.cuda.memory_allocated(device) / 2**20)

    torch.manual_seed(0)
    model = InstantNGP(BOX, backend=request["backend"], **request["config"]).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2, betas=(0.9, 0.99), eps=1e-15)
    mark("model")
    blank = np.zeros((size, size, 4), np.uint8)  # one array shared by every frame: no pixel memory
    cameras = synthetic_cameras(views + 1, size)
    scene = Scene(cameras, [Frame(f"r_{i}", image=blank) for i in range(views + 1)],
                  near_far=np.tile([2.0, 6.0], (views + 1, 1)))
    rays, colors = scene_rays(scene, range(views), model.extent, device)
    budget = RayBudget(model.target_samples)
    mark(f"rays of {views} views")
    background = torch.ones(3, device=device)
    samples = []
    started = time.perf_counter()
    for step in range(request["steps"]):  # as pointfield.fields.train.train's step()
        generator = torch.Generator().manual_seed(step)
        model.before_step(step, generator)
        indices = torch.randint(len(rays), (budget.rays(),), generator=generator).to(device)
        output = model(rays[indices], background, jitter=True, generator=generator)
        budget.update(len(indices), output.samples)
        loss = torch.mean((output.final.color - colors[indices]) ** 2)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        samples.append(len(output.final.samples))
    training_seconds = time.perf_counter() - started
    mark(f"{request['steps']} training steps")
    view, _ = scene_rays(scene, [views], model.extent, device)
    pixels = size * size
    chunk_rows = size if request["render_chunks"] is None else max(1, request["render_chunks"] * RENDER_CHUNK // size)
    first_row = max(0, size // 2 - chunk_rows // 2)
    selected = slice(first_row * size, min(pixels, (first_row + chunk_rows) * size))
    part = view[selected]
    started = time.perf_counter()
    model.eval()
    render_in_chunks(model, part, background, chunk=RENDER_CHUNK)
    render_seconds = time.perf_counter() - started
    mark(f"render {len(part)} of {pixels} pixels")
    return {"phases_mb": phases, "samples_per_step": samples, "training_seconds": training_seconds,
            "render_seconds": render_seconds, "rendered_pixels": len(part)}


def memory(config: dict[str, int], size: int, args: argparse.Namespace) -> dict:
    render_chunks = None if size <= 100 else args.render_chunks
    request = {"config": config, "size": size, "views": TRAINING_VIEWS, "steps": args.memory_steps,
               "render_chunks": render_chunks, "backend": args.memory_backend, "device": args.device}
    completed = subprocess.run([sys.executable, __file__, "--memory-child", json.dumps(request)],
                               capture_output=True, text=True, env=os.environ.copy(), check=False)
    if completed.returncode != 0:
        raise SystemExit(f"memory measurement failed for {size}x{size}:\n{completed.stderr[-4000:]}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def memory_table(record: Record, name: str, config: dict[str, int], counts: dict[str, int], size: int,
                 result: dict, backend: str) -> float:
    """Tabulate one memory measurement; returns its peak resident memory in GB."""
    phases = result["phases_mb"]
    peak = max(value[0] for key, value in phases.items() if "cuda" not in key) / 1024
    steps = ", ".join(f"{count:,}" for count in result["samples_per_step"])
    record.table(
        ["after", "peak MB", "now MB"],
        [[phase, f"{highest:.0f}", "-" if now is None else f"{now:.0f}"] for phase, (highest, now) in phases.items()],
        title=f"memory, {name} ({describe(config)}), backend {backend}: parameters bounded {counts['bounded']:,} "
              f"(hash table {counts['hash table']:,}), unbounded {counts['unbounded']:,}; peak {peak:.2f} GB = "
              f"{100 * peak / TARGET_GB:.0f} % of {TARGET_GB:.0f} GB; samples per training step {steps} "
              f"({result['training_seconds']:.1f} s); rendered {result['rendered_pixels']:,} of {size * size:,} "
              f"pixels in {result['render_seconds']:.1f} s",
    )
    return peak


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, help="lego configuration: levels (default: InstantNGP's)")
    parser.add_argument("--features", type=int, help="lego configuration: features per level")
    parser.add_argument("--log2-table", type=int, help="lego configuration: log2 of the table size")
    parser.add_argument("--max-resolution", type=int, help="lego configuration: finest resolution")
    parser.add_argument("--points", type=int, default=1 << 16, help="samples per forward + backward (default 65536)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls after the first (default 3)")
    parser.add_argument("--skip-compiled", action="store_true", help="leave out the torch.compile backend")
    parser.add_argument("--skip-throughput", action="store_true")
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 800], help="image sizes (default 100 800)")
    parser.add_argument("--memory-steps", type=int, default=3, help="training steps per size (default 3)")
    parser.add_argument("--render-chunks", type=int, default=1,
                        help="chunks of an 800x800 view rendered (default 1; views up to 100x100: all)")
    parser.add_argument("--memory-backend", default="eager", choices=("auto", "compiled", "eager"),
                        help="hash-grid backend while measuring memory (default eager: no compiler in the peak)")
    parser.add_argument("--device", default=None, help="auto (default), cpu, cuda, ...")
    parser.add_argument("--memory-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.memory_child:
        print(json.dumps(memory_child(json.loads(args.memory_child))))
        return 0

    from pointfield.devices import pick_device
    from pointfield.fields.encodings.hashgrid import _FUSED_HASH_ENCODE

    device = pick_device(args.device)
    record = Record(
        "hashgrid", "Hash encoding throughput and Instant-NGP memory", issue="6", device=device_name(device),
        about="(a) Forward + backward of the multiresolution hash encoding in samples per second: compiled "
              "(`torch.compile`), eager (hand-written backward) and the reference implementation, beside "
              "TinyNeRF's dense MLP field and the whole `NGPField`, interleaved; \"first s\" is the first call "
              "(compilation for compiled, cached on disk). One Adam step over the field's parameters, default "
              "and fused, interleaved. (b) Peak resident memory of a fresh process holding all 90 training views' "
              "rays, taking a few training steps and rendering a held-out view (at 800 x 800, the first chunks "
              "through its middle); untrained model, the worst case. `lego` is what `pointfield nerf train lego "
              "--model ngp` builds, `paper` is Müller et al. 2022 (16 levels, F = 2, 2^19 entries, N_max 2048).")
    figures, timed_compiled = record.figures, False
    for name, config_for in configurations(args).items():
        if not args.skip_throughput:
            config = config_for(THROUGHPUT_SIZE)
            print(f"\n{name}: timing ({describe(config)})", flush=True)
            rows = throughput(config, args, device)
            timed_compiled |= any(row["implementation"].endswith(", compiled") for row in rows)
            throughput_table(record, f"{name} at {THROUGHPUT_SIZE}x{THROUGHPUT_SIZE}", config, rows, args.points)
            adam = adam_step_seconds(config, args, device)
            record.note(f"{name}: one Adam step over the field's parameters (the whole table, every step), "
                        f"median of {args.repeats} interleaved: {adam['default'] * 1e3:.1f} ms; with fused=True "
                        f"{adam['fused'] * 1e3:.1f} ms.")
            figures.setdefault(name, {}).update({"config": config, "throughput": rows, "adam_seconds": adam})
        if not args.skip_memory:
            for size in args.sizes:
                config = config_for(size)
                print(f"\n{name}: memory at {size}x{size} (subprocess; {describe(config)})", flush=True)
                result = memory(config, size, args)
                counts = parameter_counts(config)
                peak = memory_table(record, f"{name} at {size}x{size}", config, counts, size, result,
                                    args.memory_backend)
                figures.setdefault(name, {}).setdefault("memory", {})[f"{size}x{size}"] = {
                    "config": config, "parameters": counts, "peak_gb": peak, **result}
                record.verdict(f"{name} at {size}x{size} trains within {TARGET_GB:.0f} GB", peak <= TARGET_GB,
                               f"peak {peak:.2f} GB")
    if timed_compiled:
        record.require_compiled(_FUSED_HASH_ENCODE)
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
