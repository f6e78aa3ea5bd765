"""The GPU path: lego at full resolution on one CUDA GPU, in pure PyTorch (no CUDA build).

The claims (issue 19), on NeRF-synthetic lego at 800 x 800 (``--downscale 1 --holdout-every
10``, white background; views 0, 10, ..., 90 held out, 90 trained on), on the first CUDA GPU:

- the hash-grid field (``--model ngp``) reaches 35 dB held-out PSNR within 300 s of training
  (the CUDA peers' figure: nerfacc's and ngp_pl's Instant-NGP, both with tiny-cuda-nn kernels);
  its PSNR at 60, 120 and 300 s is reported;
- Gaussian splats: PSNR at 300 and 600 s, and frames per second rendering a held-out view at
  800 x 800 through ``run.render``;
- PointNet and PointNet++ training samples per second on the GPU against the CPU, same run;
- the splat rasterizer's compositing block size (``max_block_elements``): a training step and a
  render of 100,000 random splats at 800 x 800 for blocks of 2^18 to 2^24 elements, the figures
  behind the GPU default (:data:`pointfield.splats.rasterizer.GPU_BLOCK_ELEMENTS`);
- geometry (issue 14): TSDF fusion of the cube's exact depth maps (24 views at 100 x 100 and 800
  x 800, 256^3 over [-1, 1]^3) on the GPU against the same machine's CPU, interleaved: depth
  maps per second and whether the two grids agree; then ``scene make textured-cube`` (100 views
  of 100 x 100), the hash-grid field trained with ``nerf train``'s defaults for the device for
  ``--geometry-seconds``, its mesh (256^3) and cloud exported on the GPU, timed, and scored
  against the true surface as ``bench_geometry.py`` scores them (Chamfer and F-score at 1 % of
  the diagonal; the goals 0.5 % and 0.9).

PSNR at a time is the last evaluation at or before that many training seconds (evaluations
excluded, :func:`harness.training_curve`, the clock of every other benchmark); held-out PSNR is
the mean of per-view PSNR over all ten held-out views. A time limit shorter than a mark leaves
that mark out; a run that finished its steps sooner keeps its final figure.

Run: ``make bench-gpu`` (= ``python benchmarks/bench_gpu.py``), or e.g. ``--ngp-seconds 120
--splat-seconds 120`` for a shorter lease (the geometry part alone: ``--parts geometry``, about
two minutes with its default 60 s of training). ``--device cpu --downscale 8`` smoke-tests it without
a GPU. The record goes to ``benchmarks/records/gpu.json`` (``gpu-geometry.json`` for ``--parts geometry``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from harness import Record, device_name, interleaved, training_curve

LEGO = Path(__file__).resolve().parents[2] / "shared" / "data" / "nerf" / "lego_blender"
NGP_MARKS = (60.0, 120.0, 300.0)
SPLAT_MARKS = (300.0, 600.0)
NGP_GOAL_DB, NGP_GOAL_SECONDS = 35.0, 300.0


def psnr_at(curve: list[dict], seconds: float) -> dict | None:
    """The last point of ``curve`` at or before ``seconds`` of training (2 % slack for the last step).

    None where the run was stopped by its time limit before the mark: its figure there is unknown.
    A run that finished its steps earlier keeps its final figure at every later mark.
    """
    before = [point for point in curve if point["training_seconds"] <= seconds * 1.02]
    return before[-1] if before else None


def model_option(text: str) -> tuple[str, int | float]:
    """``KEY=NUMBER`` from the command line -> ``(key, int or float)``."""
    key, separator, value = text.partition("=")
    if not separator or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=NUMBER, got {text!r}")
    try:
        return key, int(value)
    except ValueError:
        try:
            return key, float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number after {key}=, got {value!r}") from None


def train_scene_model(model: str, args, out: Path) -> dict:
    """Train ``model`` ("ngp" or "splat") on lego into ``out``: its curve and final figures."""
    from pointfield.training import RunDirectory

    common = {"out": out, "max_training_time": getattr(args, f"{model}_seconds"), "eval_views": 10, "progress": False,
              "downscale": args.downscale, "holdout_every": 10, "device": args.device,
              "eval_every": getattr(args, f"{model}_eval_every"), "steps": getattr(args, f"{model}_steps")}
    shutil.rmtree(out, ignore_errors=True)  # an earlier run of the benchmark's: training refuses a used folder
    started = time.perf_counter()
    options = dict(args.ngp_option) if model == "ngp" else None
    if model == "ngp":
        from pointfield.fields.train import train

        metrics = train(args.scene, model="ngp", background="white", model_options=options, **common)
    else:
        from pointfield.splats.train import train

        metrics = train(args.scene, **common)
    wall = time.perf_counter() - started
    curve = training_curve(RunDirectory(out).read_metrics_log(), metrics)
    return {"final_psnr": round(metrics["psnr"], 3), "model_options": options, "steps": metrics["steps"], "finished": metrics["steps"] >= common["steps"],
            "training_seconds": curve[-1]["training_seconds"], "outside_clock_seconds": round(wall - metrics["seconds"], 1),
            "curve": curve}


def render_seconds(out: Path, device: str, repeats: int) -> float:
    """Median seconds of one held-out 800 x 800 render through ``load_run(out).render``."""
    import pointfield
    from pointfield.scenes.heldout import training_and_heldout

    run = pointfield.load_run(out, device)
    _, heldout = training_and_heldout(run.scene)
    cameras = run.scene.cameras[heldout[:1]]

    def render():
        run.render(cameras, outputs=("rgb",))
        if run.device.type == "cuda":
            torch.cuda.synchronize(run.device)

    return interleaved({"render": render}, repeats)["render"].median


def pointnet_speed(device: torch.device, batch: int, steps: int, rounds: int) -> dict[str, float]:
    """Training samples/s (Adam, 1,024 points, 10 classes) of PointNet and PointNet++ on ``device``:
    bench_pointnet.py's measurement, on new models of the same sizes for each device."""
    from bench_pointnet import speed

    from pointfield.clouds.models import PointNet2Classifier, PointNetClassifier

    models = {"PointNet (both T-Nets)": PointNetClassifier(10), "PointNet++ SSG": PointNet2Classifier(10)}
    return {name: figures["train"] for name, figures in speed(models, batch, rounds, steps, device).items()}


def rasterizer_blocks(device: torch.device, splats: int, size: int, repeats: int) -> list[dict]:
    """Seconds of one rasterizer training step (forward + backward) and one render, by block size.

    ``splats`` random Gaussians in the unit cube seen from 4 units away at ``size`` x ``size``
    (lego's focal length scaled to the size): the compositing's ``max_block_elements`` changes
    only the speed and memory, never the images (tests/splats/test_rasterizer.py).
    """
    from pointfield.splats.rasterizer import rasterization

    generator = torch.Generator().manual_seed(0)
    means = (torch.rand(splats, 3, generator=generator) * 2 - 1).to(device)
    quats = F.normalize(torch.randn(splats, 4, generator=generator), dim=-1).to(device)
    scales = (torch.rand(splats, 3, generator=generator) * 0.02 + 0.005).to(device)
    opacities = (torch.rand(splats, generator=generator) * 0.9 + 0.05).to(device)
    colors = torch.rand(splats, 3, generator=generator).to(device)
    params = [tensor.requires_grad_() for tensor in (means, quats, scales, opacities, colors)]
    viewmat = torch.eye(4, device=device)[None].clone()
    viewmat[0, 2, 3] = 4.0
    focal = 1111.0 * size / 800
    K = torch.tensor([[[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]]], device=device)

    def synchronise():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    def train_step(block):
        colour, _, alpha, _ = rasterization(*params, viewmat, K, size, size, max_block_elements=block)
        (colour.sum() + alpha.sum()).backward()
        synchronise()

    def render(block):
        with torch.no_grad():
            rasterization(*params, viewmat, K, size, size, max_block_elements=block)
        synchronise()

    rows = []
    for mode, call in (("training step", train_step), ("render", render)):
        for block in (1 << 18, 1 << 20, 1 << 22, 1 << 24):
            if device.type == "cuda":
                torch.cuda.reset_peak_memory_stats(device)
            timing = interleaved({"block": lambda block=block, call=call: call(block)}, repeats)["block"]
            peak = torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda" else None
            rows.append({"mode": mode, "block": block, "seconds": timing.median, "peak_gib": peak})
            print(f"rasterizer {mode}, blocks of 2^{block.bit_length() - 1}: {timing.median * 1000:.1f} ms", flush=True)
    return rows


def tsdf_devices(device: torch.device, repeats: int) -> list[dict]:
    """Depth maps fused per second on ``device`` and on the CPU, and whether their grids agree:
    ``bench_tsdf.py``'s cube views and pointfield fusion, on both devices."""
    from bench_tsdf import cube_views

    rows = []
    for size in (100, 800):
        cameras, depths, colours = cube_views(24, size)
        rows.append({"size": size, "views": len(depths), **fusion_on_both(cameras, depths, colours, device, repeats)})
        print(f"tsdf {size} px: {rows[-1]}", flush=True)
    return rows


def fusion_on_both(cameras, depths, colours, device: torch.device, repeats: int) -> dict:
    """The maps fused at 256^3 on the CPU and on ``device``, interleaved: maps per second ("cpu",
    "device"), and how far the two grids differ."""
    import numpy as np
    from bench_tsdf import fuse_pointfield

    volumes = {}
    places = {"cpu": torch.device("cpu"), "device": device}

    def fusion(name):
        def run():
            volumes[name] = fuse_pointfield(cameras, depths, colours, 256, device=places[name])
        return run

    timings = interleaved({name: fusion(name) for name in places}, repeats,
                          synchronize=torch.cuda.synchronize if device.type == "cuda" else None)
    (cpu_tsdf, cpu_observed), (tsdf, observed) = volumes["cpu"].dense(), volumes["device"].dense()
    both = cpu_observed & observed
    return {"maps_per_second": {name: len(depths) / timing.median for name, timing in timings.items()},
            "observed_differ": int((cpu_observed != observed).sum()),
            "largest_tsdf_difference": float(np.abs(cpu_tsdf - tsdf)[both].max()) if both.any() else float("nan")}


def cube_geometry(args, out: Path) -> dict:
    """The textured cube's hash-grid field trained on the device; its mesh and cloud, timed and scored."""
    from bench_geometry import truth_scorer

    import pointfield
    from pointfield.clouds.formats.registry import read
    from pointfield.fields.train import train
    from pointfield.geometry import export_cloud, export_mesh
    from pointfield.geometry.compare import sample_mesh
    from pointfield.scenes.synthetic import make_scene

    data = make_scene("textured-cube", out / "textured-cube", views=100, size=100, overwrite=True)
    shutil.rmtree(out / "ngp", ignore_errors=True)  # an earlier run of the benchmark's: training refuses a used folder
    metrics = train(str(data), model="ngp", out=out / "ngp", steps=100_000, max_training_time=args.geometry_seconds,
                    device=args.device, progress=False)
    run = pointfield.load_run(out / "ngp", args.device)
    scored = truth_scorer("textured-cube", 1_000_000)
    result = {"psnr": round(metrics["psnr"], 2), "opacity_error": round(metrics["opacity_error"], 4),
              "steps": metrics["steps"], "steps_across_box": run.config["model_options"].get("steps_across_box")}
    for output, export in (("mesh", lambda path: export_mesh(run, path, resolution=256, progress=False)),
                           ("cloud", lambda path: export_cloud(run, path, progress=False))):
        path = out / f"ngp-{output}.ply"
        started = time.perf_counter()
        export(path)
        seconds = time.perf_counter() - started
        points = sample_mesh(read(path), 500_000) if output == "mesh" else read(path).points
        scores = scored(points)
        result[output] = {"seconds": round(seconds, 2), "chamfer_relative": scores["chamfer_relative"],
                          "fscore": scores["fscore"]}
        print(f"cube {output}: {result[output]}", flush=True)
    return result


def new_record(args, device: torch.device) -> Record:
    """The run's record: ``gpu`` (issue 19's lego, with whatever other parts ran), or ``gpu-geometry``
    for the geometry part alone (issue 14's), so that a geometry lease does not replace the lego record."""
    if args.parts == ["geometry"]:
        return Record(
            "gpu-geometry", "The GPU path: TSDF fusion and the textured cube's geometry", issue="14",
            device=device_name(device),
            about="TSDF fusion of the cube's exact depth maps (24 views at 100 x 100 and 800 x 800, 256^3 over "
                  "[-1, 1]^3) on the GPU and on the same machine's CPU, interleaved, median of 3 rounds; then `scene "
                  f"make textured-cube` (100 views of 100 x 100), the hash-grid field trained for "
                  f"{args.geometry_seconds:g} s with `nerf train`'s defaults for the device, its mesh (TSDF at 256^3) "
                  "and cloud exported on the GPU, timed, and scored as bench_geometry.py scores them (Chamfer in % of "
                  "the true bounding-box diagonal, F-score at 1 % of it).")
    return Record(
        "gpu", "The GPU path: lego at full resolution, PointNet on the GPU", issue="19", device=device_name(device),
        about=f"NeRF-synthetic lego at {800 // args.downscale} x {800 // args.downscale} (`--downscale {args.downscale} "
              "--holdout-every 10`, white background; 90 views trained on, 10 held out), each model trained by the "
              "function behind its command on one GPU and scored on all 10 held-out views every `--*-eval-every` "
              "steps; held-out PSNR is the mean of per-view PSNR; PSNR at a time is the last evaluation at or before "
              "that many training seconds (evaluations excluded). Renders: held-out view 0 through `run.render`, "
              f"median of {args.renders}. PointNet: training steps (Adam) on batches of {args.pointnet_batch} "
              "clouds of 1,024 points, GPU and CPU in the same run.")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=LEGO, help=f"lego, Blender format (default {LEGO})")
    parser.add_argument("--device", default="cuda", help="the GPU to measure (default cuda)")
    parser.add_argument("--downscale", type=int, default=1, help="1 = 800 x 800 (default)")
    parser.add_argument("--parts", nargs="+", choices=("ngp", "splat", "pointnet", "blocks", "geometry"),
                        default=["ngp", "splat", "pointnet", "blocks", "geometry"])
    parser.add_argument("--out", type=Path, default=Path("bench-output/gpu"), help="run folders")
    parser.add_argument("--ngp-seconds", type=float, default=300.0)
    parser.add_argument("--ngp-steps", type=int, default=20_000, help="the learning rate decays over these")
    parser.add_argument("--ngp-eval-every", type=int, default=500)
    parser.add_argument("--ngp-option", type=model_option, action="append", default=[], metavar="KEY=NUMBER",
                        help="an InstantNGP option over nerf train's defaults (on CUDA the paper's hash grid and 2^18 "
                             "samples a step, pointfield.fields.ngp.CUDA_OPTIONS), e.g. log2_table_size=17; repeatable")
    parser.add_argument("--splat-seconds", type=float, default=600.0)
    parser.add_argument("--splat-steps", type=int, default=30_000)
    parser.add_argument("--splat-eval-every", type=int, default=1000)
    parser.add_argument("--renders", type=int, default=10, help="renders timed per model (median)")
    parser.add_argument("--pointnet-batch", type=int, default=32)
    parser.add_argument("--geometry-seconds", type=float, default=60.0, help="the textured cube's training")
    args = parser.parse_args()
    if {"ngp", "splat"} & set(args.parts) and not (args.scene / "transforms_train.json").is_file():
        raise SystemExit(f"lego scene not found at {args.scene}: pass --scene or put ../shared/data beside the repo")
    from pointfield.devices import pick_device

    device = pick_device(args.device)
    args.out.mkdir(parents=True, exist_ok=True)
    record = new_record(args, device)
    results = {}
    for model in [part for part in args.parts if part in ("ngp", "splat")]:
        out = args.out / model
        results[model] = train_scene_model(model, args, out)
        results[model]["render_seconds"] = round(render_seconds(out, args.device, args.renders), 4)
        print(f"{model}: final {results[model]['final_psnr']:.2f} dB after {results[model]['training_seconds']:.0f} s "
              f"({results[model]['steps']:,} steps); render {results[model]['render_seconds']:.4f} s", flush=True)
    marks = {"ngp": NGP_MARKS, "splat": SPLAT_MARKS}
    if results:
        record.table(
            ["model", "PSNR at", "final (held-out)", "training s", "outside the clock s", "one render"],
            [[model, ", ".join(f"{mark:g} s: " + ("-" if (p := psnr_at(result["curve"], mark)) is None
                                                  or (mark > result["training_seconds"] * 1.02 and not result["finished"])
                                                  else f"{p['psnr']:.2f} dB (step {p['step']:,})")
                               for mark in marks[model]),
              f"{result['final_psnr']:.2f} dB, {result['steps']:,} steps", f"{result['training_seconds']:.1f}",
              f"{result['outside_clock_seconds']:.1f}",
              f"{result['render_seconds']:.4f} s ({1 / result['render_seconds']:.1f} fps)"]
             for model, result in results.items()])
    if "ngp" in results:
        reached = [p for p in results["ngp"]["curve"]
                   if p["psnr"] >= NGP_GOAL_DB and p["training_seconds"] <= NGP_GOAL_SECONDS * 1.02]
        record.verdict(f"ngp reaches {NGP_GOAL_DB:g} dB within {NGP_GOAL_SECONDS:g} s", bool(reached),
                       f"at {reached[0]['training_seconds']:.0f} s" if reached else
                       f"best {max(p['psnr'] for p in results['ngp']['curve']):.2f} dB")
    if "pointnet" in args.parts:
        gpu = pointnet_speed(device, args.pointnet_batch, steps=10, rounds=5)
        cpu = pointnet_speed(torch.device("cpu"), args.pointnet_batch, steps=2, rounds=3)
        results["pointnet"] = {"device": gpu, "cpu": cpu}
        record.table(["model", f"{device.type} samples/s", "cpu samples/s", "ratio"],
                     [[name, f"{gpu[name]:,.0f}", f"{cpu[name]:,.0f}", f"{gpu[name] / cpu[name]:.1f}x"] for name in gpu])
    if "blocks" in args.parts:
        size = 800 // args.downscale
        rows = rasterizer_blocks(device, splats=100_000, size=size, repeats=3)
        results["rasterizer_blocks"] = rows
        record.table(["rasterizer, 100,000 random splats", "max_block_elements", "median", "peak GPU memory"],
                     [[f"{row['mode']} at {size} x {size}", f"2^{row['block'].bit_length() - 1}",
                       f"{row['seconds'] * 1000:.1f} ms",
                       "-" if row["peak_gib"] is None else f"{row['peak_gib']:.2f} GiB"] for row in rows])
    if "geometry" in args.parts:
        rows = tsdf_devices(device, repeats=3)
        results["tsdf"] = rows
        record.table(["TSDF fusion, the cube's exact depth, 256^3", f"{device.type} maps/s", "cpu maps/s", "ratio",
                      "voxels observed by one only", "largest TSDF difference"],
                     [[f"{row['views']} views of {row['size']} x {row['size']}",
                       f"{row['maps_per_second']['device']:.1f}", f"{row['maps_per_second']['cpu']:.1f}",
                       f"{row['maps_per_second']['device'] / row['maps_per_second']['cpu']:.1f}x",
                       f"{row['observed_differ']:,}", f"{row['largest_tsdf_difference']:.2g}"] for row in rows])
        cube = cube_geometry(args, args.out / "geometry")
        results["cube"] = cube
        record.table(["textured cube, ngp", "held-out PSNR", "opacity error", "steps", "marching steps",
                      "output", "export s", "Chamfer %", "F-score"],
                     [["", f"{cube['psnr']:.2f} dB", f"{cube['opacity_error']:.4f}", f"{cube['steps']:,}",
                       str(cube["steps_across_box"]), output, f"{cube[output]['seconds']:.1f}",
                       f"{100 * cube[output]['chamfer_relative']:.3f}", f"{cube[output]['fscore']:.3f}"]
                      for output in ("mesh", "cloud")])
        from bench_geometry import GOAL_CHAMFER, GOAL_FSCORE

        for output in ("mesh", "cloud"):
            scores = cube[output]
            record.verdict(f"textured cube ngp {output} on {device.type}: Chamfer <= {100 * GOAL_CHAMFER:.1f} % of "
                           f"the diagonal, F-score >= {GOAL_FSCORE}",
                           scores["chamfer_relative"] <= GOAL_CHAMFER and scores["fscore"] >= GOAL_FSCORE,
                           f"{100 * scores['chamfer_relative']:.3f} %, F {scores['fscore']:.3f}")
    record.figures.update({"runs": str(args.out), "results": results})
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
