"""RGB-D sequences in: read the frames, pose them by odometry, fuse them into a mesh, write a scene.

::

    reconstruct_rgbd("livingroom1", "room", intrinsics="camera_primesense.json")   # scene from-rgbd

Layouts (:func:`read_rgbd_folder`)
    - ``depth/`` beside ``image/``, ``color/`` or ``rgb/`` (Redwood, open3d's reconstruction
      system): the files of each folder in sorted order, paired by name where both folders use
      the same names, else by position when they hold as many;
    - TUM RGB-D: ``rgb.txt`` and ``depth.txt`` (``timestamp path`` lines, ``#`` comments), each
      colour frame paired with the depth frame nearest in time within 0.02 s, one to one (TUM's
      ``associate.py``).
Depth
    16-bit PNG (or any integer or float image imageio reads), divided by ``depth_scale`` to give
    metres (default 1000, millimetres; 5000 for a TUM layout, as TUM stores it). Depth past
    ``depth_max`` metres is dropped (default 3, open3d's reconstruction system's ``depth_max``):
    a structured-light or time-of-flight sensor's far readings are its noisiest.
Intrinsics
    open3d's ``PinholeCameraIntrinsic`` JSON: ``{"width": 640, "height": 480,
    "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]}`` (the 3 x 3 matrix column by column),
    with open3d's principal point (pixel centres on integers); pointfield's is 0.5 more.
The pipeline (:func:`reconstruct_rgbd`)
    1. frame-to-frame odometry, generalized ICP on thinned depth clouds
       (:func:`pointfield.registration.odometry.rgbd_odometry`);
    2. on a sequence of more than twice ``fragment_size`` frames (default 100, open3d's), fragments
       of that many frames, each first through a pose graph of its own (its keyframes registered
       onto each other), registered pairwise -- consecutive ones and, with ``loop_closure``, those
       whose boxes meet (each fragment's 8 nearest) -- and a pose graph over them that prunes the loop closures it
       disagrees with (:func:`pointfield.registration.fragments.fragment_poses`): the drift of a
       camera that comes back to where it was is taken out;
    3. TSDF fusion of every frame at its pose (:class:`pointfield.geometry.tsdf.TSDFVolume`,
       truncation 4 voxels, only the blocks near each frame's surface updated by it, as
       open3d's ScalableTSDFVolume does, found from every few pixels' rays:
       :func:`pointfield.geometry.tsdf.allocation_stride`; each voxel reads the depth of the pixel it
       falls in, as open3d does, unless pixels at ``depth_max`` are wider than a voxel), over the
       box of the posed clouds;
    4. marching cubes, floaters dropped (:func:`pointfield.geometry.meshes.mesh_from_volume`).
What comes out (one folder, written whole or not at all)
    ``transforms.json`` (nerfstudio format: posed colour images with ``depth_file_path`` and
    ``depth_unit_scale_factor``; ``nerf train`` and ``splat train`` read it, the splats start
    from ``cloud.ply``), ``images/`` and ``depth/`` (the input files, copied byte for byte),
    ``mesh.ply``, ``cloud.ply`` (the mesh's vertices with colours and normals),
    ``trajectory.txt`` (TUM: ``timestamp tx ty tz qx qy qz qw``, camera-to-world),
    ``trajectory.log`` (open3d / Redwood: ``i i i+1`` then the 4 x 4 camera-to-world matrix)
    and ``report.json`` (settings, times, odometry fitness, fragments and loop closures, warnings).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.errors import FormatError, OptionError, PointfieldError
from pointfield.registration.fragments import DEFAULT_FRAGMENT_SIZE, KEYFRAME_INTERVAL, FragmentPoses, fragment_poses
from pointfield.registration.odometry import Intrinsics, rgbd_odometry

COLOUR_FOLDERS = ("image", "color", "colour", "rgb")
"""Names of the colour folder beside ``depth/``, in the order they are looked for."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
TUM_MAX_DIFFERENCE = 0.02
"""Seconds: a TUM colour frame and a depth frame further apart in time are not paired (TUM's associate.py)."""
DEFAULT_DEPTH_SCALE = {"folders": 1000.0, "tum": 5000.0}


@dataclass
class RGBDFrames:
    """The frames of a sequence: paths of colour and depth images, paired, in time order.

    ``timestamps`` ``(N,)`` seconds for a TUM layout, else the frame indices. ``layout``:
    ``"folders"`` or ``"tum"``.
    """

    root: Path
    colour: list[Path]
    depth: list[Path]
    timestamps: np.ndarray
    layout: str

    def __len__(self) -> int:
        return len(self.depth)

    def subset(self, count: int) -> RGBDFrames:
        """The first ``count`` frames."""
        return RGBDFrames(self.root, self.colour[:count], self.depth[:count], self.timestamps[:count], self.layout)


def read_rgbd_folder(folder: str | os.PathLike[str]) -> RGBDFrames:
    """The paired frames of ``folder`` in either layout of the module docstring, or a :class:`PointfieldError` saying why not."""
    root = Path(folder)
    if not root.is_dir():
        raise PointfieldError(f"{root}: no such folder; expected an RGB-D sequence (depth/ + image/, or TUM rgb.txt + depth.txt)")
    if (root / "rgb.txt").is_file() and (root / "depth.txt").is_file():
        return _read_tum(root)
    depth_folder = root / "depth"
    colour_folder = next((root / name for name in COLOUR_FOLDERS if (root / name).is_dir()), None)
    if not depth_folder.is_dir() or colour_folder is None:
        missing = "depth/" if not depth_folder.is_dir() else f"a colour folder ({', '.join(COLOUR_FOLDERS)})"
        raise PointfieldError(f"{root}: no {missing}; expected depth/ beside image/ or color/, or TUM's rgb.txt "
                              "and depth.txt")
    depth, colour = _images_in(depth_folder), _images_in(colour_folder)
    if not depth or not colour:
        empty = depth_folder if not depth else colour_folder
        raise PointfieldError(f"{empty}: no images ({', '.join(IMAGE_SUFFIXES)})")
    depth_stems, colour_stems = [p.stem for p in depth], [p.stem for p in colour]
    if set(depth_stems) == set(colour_stems):
        by_stem = {p.stem: p for p in colour}
        colour = [by_stem[stem] for stem in depth_stems]
    elif len(depth) != len(colour):
        only_depth = sorted(set(depth_stems) - set(colour_stems))
        listed = ", ".join(only_depth[:3]) + (", ..." if len(only_depth) > 3 else "")
        raise PointfieldError(f"{root}: unpaired frames: {len(depth)} depth images in {depth_folder.name}/ but "
                              f"{len(colour)} colour images in {colour_folder.name}/"
                              + (f" (depth without colour: {listed})" if only_depth else ""))
    return RGBDFrames(root, colour, depth, np.arange(len(depth), dtype=np.float64), "folders")


def _images_in(folder: Path) -> list[Path]:
    """Image files of ``folder`` in natural order (``2.png`` before ``10.png``)."""
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)])


def _read_tum_list(path: Path) -> list[tuple[float, Path]]:
    entries = []
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            stamp = float(parts[0])
        except ValueError:
            raise FormatError(path, f"line {number}: expected 'timestamp filename', got {line[:60]!r}") from None
        if len(parts) < 2 or not math.isfinite(stamp):
            raise FormatError(path, f"line {number}: expected 'timestamp filename', got {line[:60]!r}")
        entries.append((stamp, path.parent / parts[1]))
    if not entries:
        raise FormatError(path, "lists no frames")
    return entries


def _read_tum(root: Path) -> RGBDFrames:
    colour, depth = _read_tum_list(root / "rgb.txt"), _read_tum_list(root / "depth.txt")
    depth_stamps = np.array([stamp for stamp, _ in depth])
    # Every close pair, nearest first; each frame used once (associate.py's greedy rule).
    candidates = sorted((abs(c - depth_stamps[j]), i, j) for i, (c, _) in enumerate(colour)
                        for j in np.nonzero(np.abs(depth_stamps - c) < TUM_MAX_DIFFERENCE)[0])
    used_colour, used_depth, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_colour and j not in used_depth:
            used_colour.add(i), used_depth.add(j), pairs.append((i, int(j)))
    if not pairs:
        raise PointfieldError(f"{root}: unpaired frames: no colour frame of rgb.txt lies within {TUM_MAX_DIFFERENCE} s "
                              "of a depth frame of depth.txt")
    pairs.sort()
    for i, j in pairs:
        for path in (colour[i][1], depth[j][1]):
            if not path.is_file():
                raise PointfieldError(f"{path}: listed in {root.name}/{'rgb' if path == colour[i][1] else 'depth'}.txt "
                                      "but missing")
    return RGBDFrames(root, [colour[i][1] for i, _ in pairs], [depth[j][1] for _, j in pairs],
                      np.array([colour[i][0] for i, _ in pairs]), "tum")


def read_intrinsics(path: str | os.PathLike[str]) -> Intrinsics:
    """open3d's ``PinholeCameraIntrinsic`` JSON (module docstring) as pointfield :class:`Intrinsics`."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise PointfieldError(f"{path}: no such intrinsics file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise FormatError(path, f"not a JSON file of camera intrinsics ({error})") from None
    expected = ('expected open3d\'s {"width": W, "height": H, "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]} '
                "(column by column)")
    if not isinstance(document, dict) or not {"width", "height", "intrinsic_matrix"} <= set(document):
        raise FormatError(path, expected)
    width, height, matrix = document["width"], document["height"], document["intrinsic_matrix"]
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (width, height)):
        raise FormatError(path, f"width and height must be positive integers, got {width!r} and {height!r}")
    if (not isinstance(matrix, list) or len(matrix) != 9
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in matrix)):
        raise FormatError(path, f"intrinsic_matrix must be 9 numbers; {expected}")
    k = np.asarray(matrix, np.float64).reshape(3, 3).T  # column-major
    if not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]) or k[1, 0] != 0:
        raise FormatError(path, f"intrinsic_matrix is not a pinhole camera's (fx, fy > 0, last row 0 0 1): "
                          f"{k.tolist()}")
    return Intrinsics(width, height, float(k[0, 0]), float(k[1, 1]), float(k[0, 2]) + 0.5, float(k[1, 2]) + 0.5)


def find_intrinsics(root: Path) -> Path:
    """The one intrinsics JSON of a sequence folder (``camera*.json``, ``intrinsic*.json``), when none is given."""
    found = sorted({*root.glob("camera*.json"), *root.glob("intrinsic*.json")})
    if len(found) != 1:
        what = "none" if not found else ", ".join(p.name for p in found)
        raise OptionError(f"{root}: give the camera with intrinsics=... (found {what} of camera*.json, intrinsic*.json)",
                          command_line=f"{root}: give the camera with --intrinsics camera.json (found {what} of "
                          "camera*.json, intrinsic*.json)")
    return found[0]


def read_depth(path: Path, intrinsics: Intrinsics, depth_scale: float, depth_max: float) -> np.ndarray:
    """``(H, W)`` float32 z-depth in metres (0 = none) of one depth image; checked against the intrinsics' size."""
    image = _read_image(path, "depth")
    if image.ndim != 2:
        raise FormatError(path, f"a depth image has one channel, this one has shape {image.shape}")
    _check_size(path, image, intrinsics, "depth")
    depth = image.astype(np.float32) / np.float32(depth_scale)
    depth[~np.isfinite(depth) | (depth < 0) | (depth > depth_max)] = 0.0
    return depth


def read_colour(path: Path, intrinsics: Intrinsics) -> np.ndarray:
    """``(H, W, 3)`` float32 colour in [0, 1] of one colour image (grey repeated, alpha dropped)."""
    image = _read_image(path, "colour")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise FormatError(path, f"expected an RGB image, got shape {image.shape}")
    _check_size(path, image, intrinsics, "colour")
    scale = float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else 1.0
    return image[:, :, :3].astype(np.float32) / np.float32(scale)


def _read_image(path: Path, what: str) -> np.ndarray:
    import imageio.v3 as iio

    try:
        return np.asarray(iio.imread(path))
    except FileNotFoundError:
        raise PointfieldError(f"{path}: no such {what} image") from None
    except Exception as error:  # noqa: BLE001 -- imageio raises many types for a damaged file
        raise FormatError(path, f"not a readable {what} image ({type(error).__name__}: {error})") from None


def _check_size(path: Path, image: np.ndarray, intrinsics: Intrinsics, what: str) -> None:
    if image.shape[:2] != (intrinsics.height, intrinsics.width):
        raise FormatError(path, f"the {what} image is {image.shape[1]}x{image.shape[0]} but the intrinsics say "
                          f"{intrinsics.width}x{intrinsics.height}; depth and colour must match the camera")


@dataclass
class RGBDReconstruction:
    """What :func:`reconstruct_rgbd` made: where, the trajectory, and the figures of the run."""

    out: Path
    poses: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)

    def format(self) -> str:
        r = self.report
        lines = [
            f"wrote {self.out}: {r['frames']} frames posed and fused",
            (f"  odometry: generalized ICP frame to frame, voxel {r['odometry_voxel']:g} m, fitness min "
             f"{r['fitness_min']:.3f} mean {r['fitness_mean']:.3f}, {r['seconds']['odometry']:.1f} s"),
            self._fragment_line(),
            (f"  fusion: TSDF voxel {r['voxel']:g} m, grid {'x'.join(map(str, r['grid']))}, "
             f"{r['seconds']['fusion']:.1f} s; mesh {r['vertices']} vertices, {r['faces']} faces"),
            (f"  total {r['seconds']['total']:.1f} s; mesh.ply, cloud.ply, trajectory.txt (TUM), trajectory.log, "
             "transforms.json (nerf train / splat train)"),
        ]
        lines += [f"  warning: {w}" for w in r.get("warnings", [])]
        return "\n".join(line for line in lines if line)

    def _fragment_line(self) -> str:
        f, r = self.report.get("fragments", {}), self.report
        if not f.get("used"):
            return f"  fragments: none ({f['why']})" if f else ""
        within = f.get("keyframe_pairs", [0, 0, 0])
        own = (f"each with its own pose graph (keyframes every {f.get('keyframe_every', KEYFRAME_INTERVAL)} frames, "
               f"{within[0]} keyframe pairs, {within[2]} pruned)" if f.get("keyframe_every", KEYFRAME_INTERVAL)
               else "the odometry kept within each (--keyframe-every 0)")
        line = (f"  fragments: {f['count']} of {f['size']} frames, {own}, pose graph over them, "
                f"{r['seconds'].get('fragments', 0.0):.1f} s; ")
        if not f["loop_closure"]:
            return line + "loop closures not tried (--no-loop-closure)"
        return line + (f"loop closures: {f['loop_candidates']} pairs tried, {f['loops_registered']} registered, "
                       f"{f['loops_kept']} kept, {f['loops_pruned']} pruned")


def reconstruct_rgbd(folder: str | os.PathLike[str], out: str | os.PathLike[str], *,
                     intrinsics: str | os.PathLike[str] | None = None, depth_scale: float | None = None,
                     depth_max: float = 3.0, voxel: float = 0.01, odometry_voxel: float = 0.02, stride: int = 2,
                     frames: int | None = None, fragment_size: int = DEFAULT_FRAGMENT_SIZE, loop_closure: bool = True,
                     keyframe_every: int = KEYFRAME_INTERVAL,
                     overwrite: bool = False, device: str | None = None, fusion_threads: int | None = 1,
                     progress: bool = True) -> RGBDReconstruction:
    """Pose and fuse the RGB-D sequence in ``folder`` and write the scene folder ``out`` (module docstring).

    ``intrinsics``: the camera's JSON (default: the folder's one ``camera*.json``); ``depth_scale``:
    stored depth units per metre; ``depth_max``: metres; ``voxel``: the TSDF's voxel (metres);
    ``odometry_voxel``, ``stride``: see :func:`~pointfield.registration.odometry.rgbd_odometry`;
    ``frames``: only the first so many. ``fragment_size``: a sequence of more than twice this many
    frames is cut into fragments of so many, registered pairwise and put through a pose graph
    (:func:`~pointfield.registration.fragments.fragment_poses`; 0: never); ``loop_closure``: with
    fragments, register non-consecutive ones too (loop closures); ``keyframe_every``: within each
    fragment every so many frames a keyframe, registered onto its nearest keyframes for the fragment's
    own pose graph (default 5, open3d's; 0: none, the odometry kept within fragments).
    ``fusion_threads``: torch threads while fusing on the CPU
    (default 1; None leaves torch's setting): each frame is a few dozen elementwise passes over
    about a million voxels, too little to share -- 15 of the living room's frames fused in 6.8 s
    on one thread and 13.6 s on two of a 2-core machine shared with other jobs (docs/rgbd.md).
    ``progress``: a bar over the frames, once for the odometry and once for the fusion (on a terminal).
    """
    import torch

    from pointfield.devices import pick_device
    from pointfield.geometry.meshes import mesh_from_volume
    from pointfield.geometry.tsdf import TSDFVolume, allocation_stride
    from pointfield.scenes.cameras import Cameras
    from pointfield.scenes.formats.registry import atomic_directory
    from pointfield.training.console import progress_bar

    started = time.perf_counter()
    sequence = read_rgbd_folder(folder)
    camera = read_intrinsics(intrinsics if intrinsics is not None else find_intrinsics(sequence.root))
    scale = DEFAULT_DEPTH_SCALE[sequence.layout] if depth_scale is None else float(depth_scale)
    for name, value in (("depth_scale", scale), ("depth_max", depth_max), ("voxel", voxel),
                        ("odometry_voxel", odometry_voxel)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            flag = "--" + name.replace("_", "-")
            raise OptionError(f"{name} must be a positive number, got {value}",
                              command_line=f"{flag} must be a positive number, got {value}")
    if fusion_threads is not None and fusion_threads < 1:
        raise OptionError(f"fusion_threads must be 1 or more, got {fusion_threads}",
                          command_line=f"--fusion-threads must be 0 (torch's own) or more, got {fusion_threads}")
    if not (isinstance(fragment_size, int) and fragment_size >= 0):
        raise OptionError(f"fragment_size must be 0 (no fragments) or more, got {fragment_size}",
                          command_line=f"--fragment-size must be 0 (no fragments) or more, got {fragment_size}")
    if not (isinstance(keyframe_every, int) and keyframe_every >= 0):
        raise OptionError(f"keyframe_every must be 0 (no keyframes) or more, got {keyframe_every}",
                          command_line=f"--keyframe-every must be 0 (no keyframes) or more, got {keyframe_every}")
    if frames is not None:
        if frames < 1:
            raise OptionError(f"frames must be 1 or more, got {frames}", command_line=f"--frames must be 1 or more, got {frames}")
        sequence = sequence.subset(frames)
    out = Path(out)
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise PointfieldError(f"{out}: directory exists and is not empty (pass overwrite to replace it)",
                              command_line=f"{out}: directory exists and is not empty (pass --overwrite to replace it)")

    def depths():
        with progress_bar(progress, total=len(sequence), desc="odometry", unit="frame") as bar:
            for path in sequence.depth:
                yield read_depth(path, camera, scale, depth_max)
                bar.update(1)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        in_fragments = bool(fragment_size) and len(sequence) > 2 * fragment_size
        # The fragments' own pose graphs weigh each step by its information: measured in the odometry's k-d trees.
        odometry = rgbd_odometry(depths(), camera, voxel=odometry_voxel, stride=stride,
                                 information=in_fragments and keyframe_every > 0)
        odometry_done = time.perf_counter()
        poses, fragments = odometry.poses, None
        if in_fragments:
            fragments = fragment_poses(odometry.poses, odometry.points, fragment_size, voxel=odometry_voxel,
                                       loop_closure=loop_closure, keyframe_interval=keyframe_every or None,
                                       information=odometry.information or None)
            poses = fragments.poses
    fragments_done = time.perf_counter()

    # The box: the posed thinned clouds, padded by the truncation and a voxel so that surfaces on its faces mesh.
    world = np.concatenate([p @ pose[:3, :3].T + pose[:3, 3] for p, pose in zip(odometry.points, poses)])
    if len(world) == 0:
        raise PointfieldError(f"{sequence.root}: no depth within {depth_max} m in any frame; nothing to fuse "
                              "(check depth_scale and depth_max)")
    pad = 5 * voxel
    low, high = world.min(axis=0) - pad, world.max(axis=0) + pad
    resolution = max(2, math.ceil(float(np.max(high - low)) / voxel))
    device = pick_device(device)
    volume = TSDFVolume.create(low, high, resolution, truncation_voxels=4.0, device=device,
                               memory_limit=_memory_limit())
    cameras = Cameras(torch.as_tensor(poses), camera.fx, camera.fy, camera.cx, camera.cy,
                      camera.width, camera.height)
    stride_for_blocks = allocation_stride(volume.voxel, min(camera.fx, camera.fy), depth_max)
    # Interpolating depth between pixels only pays where pixels are wider than voxels (geometry/tsdf.py).
    interpolate = depth_max / min(camera.fx, camera.fy) > volume.voxel
    threads_before = torch.get_num_threads()
    if device.type == "cpu" and fusion_threads is not None:
        torch.set_num_threads(fusion_threads)
    try:
        frames_with_bar = progress_bar(progress, iterable=zip(sequence.depth, sequence.colour), total=len(sequence),
                                       desc="fusion", unit="frame")
        for index, (depth_path, colour_path) in enumerate(frames_with_bar):
            depth = torch.from_numpy(read_depth(depth_path, camera, scale, depth_max))
            colour = torch.from_numpy(read_colour(colour_path, camera))
            volume.integrate(depth, colour, cameras, index, touched_only=True, pixel_stride=stride_for_blocks,
                             interpolate=interpolate)
    finally:
        torch.set_num_threads(threads_before)
    mesh = mesh_from_volume(volume)
    fused = time.perf_counter()

    notes = [str(w.message) for w in caught]
    report = {
        "frames": len(sequence), "layout": sequence.layout, "source": str(sequence.root),
        "intrinsics": {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
                       "cx": camera.cx, "cy": camera.cy, "convention": "pixel centres at +0.5 (open3d's cx + 0.5)"},
        "depth_scale": scale, "depth_max": depth_max, "voxel": voxel, "odometry_voxel": odometry_voxel,
        "stride": stride, "odometry": "generalized ICP (small_gicp), frame to frame, from the last motion",
        "fitness_min": float(odometry.fitness.min()) if len(odometry.fitness) else 1.0,
        "fitness_mean": float(odometry.fitness.mean()) if len(odometry.fitness) else 1.0,
        "grid": list(volume.shape), "box": [low.tolist(), high.tolist()],
        "vertices": len(mesh.points), "faces": len(mesh.faces), "device": str(device),
        "fusion_threads": fusion_threads or threads_before, "warnings": notes,
        "fragments": _fragment_report(fragments, fragment_size, loop_closure, len(sequence), keyframe_every),
    }
    with atomic_directory(out, overwrite=overwrite) as directory:
        _write_outputs(directory, sequence, camera, scale, poses, mesh)
        report["seconds"] = {"odometry": odometry_done - started, "fragments": fragments_done - odometry_done,
                             "fusion": fused - fragments_done,
                             "total": time.perf_counter() - started}
        (directory / "report.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return RGBDReconstruction(out, poses, report)


def _fragment_report(fragments: FragmentPoses | None, size: int, loop_closure: bool, count: int,
                     keyframe_every: int) -> dict[str, Any]:
    """What the fragment stage did, for ``report.json`` and the summary: nothing, or fragments and pose-graph edges."""
    if fragments is None:
        why = "--fragment-size 0" if not size else f"{count} frames, not more than twice the fragment size {size}"
        return {"used": False, "size": size, "why": why}
    return {"used": True, "size": size, "count": len(fragments.fragments), "ranges": fragments.fragments,
            "loop_closure": loop_closure, "loop_candidates": fragments.loop_candidates,
            "keyframe_every": keyframe_every, "keyframe_pairs": list(fragments.keyframe_pairs),
            "loops_registered": sum(p.kind == "loop closure" for p in fragments.pairs),
            "loops_kept": fragments.loops_kept, "loops_pruned": fragments.loops_pruned,
            "edges": [{"source": p.source, "target": p.target, "kind": p.kind, "how": p.how,
                       "fitness": p.fitness, "kept": p.kept} for p in fragments.pairs],
            "notes": fragments.notes}


def _memory_limit() -> int:
    """Bytes the TSDF may take: the share of the machine's memory that ``nerf export --mesh`` allows its grid."""
    from pointfield.geometry.meshes import DEFAULT_MEMORY_FRACTION

    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") * DEFAULT_MEMORY_FRACTION)
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def _write_outputs(directory: Path, sequence: RGBDFrames, camera: Intrinsics, depth_scale: float,
                   poses: np.ndarray, mesh) -> None:
    from pointfield.clouds.cloud import PointCloud
    from pointfield.clouds.formats.registry import write
    from pointfield.scenes.cameras import opencv_to_opengl
    from pointfield.scenes.formats.transforms_json import write_json

    write(directory / "mesh.ply", mesh)
    write(directory / "cloud.ply", PointCloud(mesh.points, {"colors": mesh.fields["colors"],
                                                            "normals": _vertex_normals(mesh)}))
    write_tum_trajectory(directory / "trajectory.txt", poses, sequence.timestamps)
    write_log_trajectory(directory / "trajectory.log", poses)
    (directory / "images").mkdir()
    (directory / "depth").mkdir()
    frames = []
    for index, (colour, depth, pose) in enumerate(zip(sequence.colour, sequence.depth, poses)):
        image_name = f"images/{index:05d}{colour.suffix.lower()}"
        depth_name = f"depth/{index:05d}{depth.suffix.lower()}"
        shutil.copyfile(colour, directory / image_name)
        shutil.copyfile(depth, directory / depth_name)
        frames.append({"file_path": image_name, "depth_file_path": depth_name,
                       "transform_matrix": opencv_to_opengl(pose).tolist()})
    write_json(directory / "transforms.json", {
        "camera_model": "PINHOLE", "w": camera.width, "h": camera.height, "fl_x": camera.fx, "fl_y": camera.fy,
        "cx": camera.cx, "cy": camera.cy, "depth_unit_scale_factor": 1.0 / depth_scale,
        "ply_file_path": "cloud.ply", "frames": frames,
    })


def _vertex_normals(mesh) -> np.ndarray:
    """``(V, 3)`` float32 unit vertex normals of ``mesh``, by trimesh (faces wound counter-clockwise seen from outside)."""
    import trimesh

    return np.asarray(trimesh.Trimesh(mesh.points, mesh.faces, process=False).vertex_normals, np.float32)


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """``(4,)`` unit quaternion ``(qx, qy, qz, qw)`` of a 3 x 3 rotation, ``qw >= 0``."""
    from scipy.spatial.transform import Rotation

    quaternion = Rotation.from_matrix(rotation).as_quat()
    return quaternion if quaternion[3] >= 0 else -quaternion


def write_tum_trajectory(path: Path, poses: np.ndarray, timestamps: np.ndarray) -> None:
    """TUM's trajectory format: one ``timestamp tx ty tz qx qy qz qw`` line per camera-to-world pose."""
    lines = ["# timestamp tx ty tz qx qy qz qw (camera-to-world, OpenCV camera axes)"]
    for stamp, pose in zip(timestamps, poses):
        values = [*pose[:3, 3], *rotation_to_quaternion(pose[:3, :3])]
        lines.append(f"{stamp:.6f} " + " ".join(f"{v:.9f}" for v in values))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_log_trajectory(path: Path, poses: np.ndarray) -> None:
    """open3d's / Redwood's ``.log``: per frame a line ``i i i+1`` then its 4 x 4 camera-to-world matrix."""
    lines = []
    for index, pose in enumerate(poses):
        lines.append(f"{index} {index} {index + 1}")
        lines += [" ".join(f"{v:.8f}" for v in row) for row in pose]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_log_trajectory(path: str | os.PathLike[str]) -> np.ndarray:
    """``(N, 4, 4)`` the poses of an open3d / Redwood ``.log`` file (a metadata line, then four rows, per frame)."""
    path = Path(path)
    try:
        rows = [line.split() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as error:
        raise FormatError(path, f"not a readable .log trajectory ({error})") from None
    if len(rows) % 5:
        raise FormatError(path, f"{len(rows)} lines; a .log trajectory has 5 per frame (metadata, then 4 x 4)")
    try:
        poses = np.array([[[float(v) for v in rows[i + k]] for k in range(1, 5)] for i in range(0, len(rows), 5)])
    except ValueError as error:
        raise FormatError(path, f"not a .log trajectory ({error})") from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise FormatError(path, "each frame's matrix must be 4 rows of 4 numbers")
    return poses


__all__ = ["RGBDFrames", "RGBDReconstruction", "find_intrinsics", "read_colour", "read_depth", "read_intrinsics",
           "read_log_trajectory", "read_rgbd_folder", "reconstruct_rgbd", "write_log_trajectory",
           "write_tum_trajectory"]
