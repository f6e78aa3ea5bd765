"""The peer of ``scene from-images``: the command-line COLMAP pipeline that nerfstudio's ``ns-process-data images`` runs.

nerfstudio (``nerfstudio/process_data/colmap_utils.py``, ``run_colmap``) runs, on the CPU::

    colmap feature_extractor --database_path DB --image_path IMAGES --ImageReader.single_camera 1
                             --ImageReader.camera_model OPENCV --SiftExtraction.use_gpu 0
    colmap exhaustive_matcher --database_path DB --SiftMatching.use_gpu 0
    colmap mapper --database_path DB --image_path IMAGES --output_path SPARSE
                  --Mapper.ba_global_function_tolerance=1e-6
    colmap bundle_adjuster --input_path SPARSE/0 --output_path SPARSE/0
                           --BundleAdjustment.refine_principal_point 1

Two differences, both to compare like with like: features are computed on images resized to
``max_image_size`` (``--SiftExtraction.max_image_size``; nerfstudio leaves COLMAP's 3200, while
pointfield's default is 800), and matching is exhaustive (nerfstudio's default, ``vocab_tree``,
downloads a vocabulary tree at run time). Threads are set for every stage. Debian's ``colmap``
package (3.8 here) runs headless for these commands (no GPU, no display).

    python benchmarks/colmap_cli.py IMAGES [WORK]     # try it by hand: stage times, registered
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class ColmapCliResult:
    """Seconds per stage, the registered images' camera-to-world ``(3, 4)`` (OpenCV), the commands run."""

    stage_seconds: dict[str, float]
    camera_to_world: dict[str, np.ndarray]
    images: int
    version: str
    commands: list[list[str]] = field(default_factory=list)


def colmap_available() -> str | None:
    """The installed COLMAP's version line ("COLMAP 3.8 ..."), or None without one."""
    if shutil.which("colmap") is None:
        return None
    output = subprocess.run(["colmap", "help"], capture_output=True, text=True, check=False).stdout
    line = next((line for line in output.splitlines() if line.startswith("COLMAP")), "COLMAP (unknown version)")
    return line.strip()


def run_colmap_cli(
    images: Path,
    work: Path,
    *,
    max_image_size: int = 800,
    camera_model: str = "OPENCV",
    threads: int = 2,
) -> ColmapCliResult:
    """Run the four commands of the module docstring on ``images`` inside ``work``; read the largest model."""
    from pointfield.scenes.formats.colmap.folder import read_colmap_model
    from pointfield.scenes.formats.colmap.scene import image_camera_to_world

    version = colmap_available()
    if version is None:
        raise RuntimeError("colmap is not installed (Debian: apt-get install colmap)")
    work.mkdir(parents=True, exist_ok=True)
    database, sparse, log = work / "database.db", work / "sparse", work / "colmap.log"
    database.unlink(missing_ok=True)
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir()
    stages = {
        "features": ["colmap", "feature_extractor", "--database_path", str(database), "--image_path", str(images),
                     "--ImageReader.single_camera", "1", "--ImageReader.camera_model", camera_model,
                     "--SiftExtraction.use_gpu", "0", "--SiftExtraction.max_image_size", str(max_image_size),
                     "--SiftExtraction.num_threads", str(threads)],
        "matching": ["colmap", "exhaustive_matcher", "--database_path", str(database),
                     "--SiftMatching.use_gpu", "0", "--SiftMatching.num_threads", str(threads)],
        "mapping": ["colmap", "mapper", "--database_path", str(database), "--image_path", str(images),
                    "--output_path", str(sparse), "--Mapper.ba_global_function_tolerance=1e-6",
                    "--Mapper.num_threads", str(threads)],
        "bundle adjustment": ["colmap", "bundle_adjuster", "--input_path", str(sparse / "0"),
                              "--output_path", str(sparse / "0"), "--BundleAdjustment.refine_principal_point", "1"],
    }
    seconds: dict[str, float] = {}
    with log.open("w") as output:
        for stage, command in stages.items():
            if stage == "bundle adjustment" and not (sparse / "0").is_dir():
                break  # the mapper made no model: nothing to refine
            start = time.perf_counter()
            done = subprocess.run(command, stdout=output, stderr=subprocess.STDOUT, check=False,
                                  env={"QT_QPA_PLATFORM": "offscreen", "PATH": "/usr/bin:/bin"})
            seconds[stage] = time.perf_counter() - start
            if done.returncode != 0:
                output.flush()
                tail = "\n".join(log.read_text(errors="replace").splitlines()[-15:])
                raise RuntimeError(f"colmap {command[1]} failed ({done.returncode}):\n{tail}")
    models = [folder for folder in sparse.iterdir() if (folder / "images.bin").is_file()]
    poses: dict[str, np.ndarray] = {}
    if models:
        largest = max((read_colmap_model(folder) for folder in models), key=lambda model: len(model.images))
        poses = {image.name: image_camera_to_world(image, sparse)[:3] for image in largest.images.values()}
    count = sum(1 for p in images.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    return ColmapCliResult(seconds, poses, count, version, list(stages.values()))


if __name__ == "__main__":
    folder = Path(sys.argv[1])
    result = run_colmap_cli(folder, Path(sys.argv[2]) if len(sys.argv) > 2 else Path("bench-output/colmap-cli"))
    print(result.version)
    print(", ".join(f"{stage} {s:.1f} s" for stage, s in result.stage_seconds.items()))
    print(f"registered {len(result.camera_to_world)} of {result.images}")
