# The two commands of the README: `make demo` and `make test` set everything up on a fresh machine.
PYTHON ?= python3.11
VENV ?= .venv
# Installed before the package so that pip never resolves a bare `torch` to a multi-GB CUDA build.
# Choose another build with e.g. `make test TORCH="torch==2.13.0 --index-url <your index>"`.
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test test-guides lint docs bench bench-report bench-formats bench-fuzz bench-ptx bench-pointnet bench-nerf bench-splat bench-splat-render bench-hashgrid bench-march bench-lego bench-lego-400 bench-sfm bench-tsdf bench-geometry bench-backgrounds bench-streaming bench-viewer bench-browser-cost bench-registration bench-align bench-sdf bench-poisson bench-occupancy bench-scenes bench-splat-resolution bench-near bench-sdf-field bench-rgbd bench-photos bench-predict bench-threads bench-ground clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet $(TORCH)
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $@

demo: $(BIN)/.installed
	$(BIN)/pointfield demo --out demo-output

# Lint and the API reference first, so that a new ruff finding or a broken reference fails CI.
# One worker per core (pytest-xdist), each folder's tests on one worker: tests/conftest.py.
test: lint docs $(BIN)/.chromium
	$(BIN)/python -m pytest -q -n auto --durations=15

# The README's and the guides' commands in the order written (tests/guides, also part of `make test`), alone.
test-guides: $(BIN)/.installed
	$(BIN)/python -m pytest -q -s tests/guides

lint: $(BIN)/.installed
	$(BIN)/ruff check src tests benchmarks docs

# The API reference (Sphinx autodoc + napoleon) from the docstrings into docs/_build/api/index.html. Warnings
# are errors, and the build fails when a public class or function is missing from it (docs/api/conf.py).
docs: $(BIN)/.installed
	$(BIN)/python -m sphinx -b html -W --keep-going -q -j auto docs/api docs/_build/api

# open3d's wheel links libusb; Debian machines without it get it from apt.
$(BIN)/.open3d: $(BIN)/.installed
	$(BIN)/python -c "import open3d" 2>/dev/null || (apt-get install -y -qq libusb-1.0-0 >/dev/null)
	$(BIN)/python -c "import open3d"
	touch $@

# The viewer's browser tests (and bench-viewer) drive Debian's chromium through playwright; playwright
# never downloads a browser. Where apt cannot install it (not root, not Debian) those tests skip, saying why.
$(BIN)/.chromium: $(BIN)/.installed
	command -v chromium >/dev/null || (apt-get update -qq && apt-get install -y -qq chromium >/dev/null) \
		|| echo "chromium could not be installed: the viewer's browser tests will skip"
	touch $@

# The SfM benchmark's peer: the COLMAP command line that nerfstudio's ns-process-data runs (Debian's package).
$(BIN)/.colmap: $(BIN)/.installed
	command -v colmap >/dev/null || (apt-get update -qq && apt-get install -y -qq colmap >/dev/null)
	colmap help >/dev/null
	touch $@

# Each benchmark writes its record to benchmarks/records/<name>.json; bench-report turns the records
# into benchmarks/RESULTS.md, each section headed by the command that produced it.
bench: bench-formats bench-fuzz bench-ptx bench-fps bench-pointnet bench-hashgrid bench-march bench-splat-render bench-lego bench-lego-400 bench-nerf bench-splat bench-sfm bench-tsdf bench-geometry bench-backgrounds bench-streaming bench-viewer bench-browser-cost bench-registration bench-align bench-sdf bench-poisson bench-occupancy bench-scenes bench-splat-resolution bench-near bench-sdf-field bench-rgbd bench-photos bench-predict bench-threads bench-ground
	$(MAKE) bench-report

bench-report: $(BIN)/.installed
	$(BIN)/python benchmarks/report.py

bench-formats: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_formats.py

bench-fuzz: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_fuzz.py

bench-ptx: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_ptx.py

bench-fps: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_fps.py

bench-pointnet: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_pointnet.py

bench-scenes: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_scenes.py

# segment predict --memory 2GB on a generated 10 M point LAZ (../bench-output/predict), PointNet++ and PTv3;
# shorter: make bench-predict PREDICT_POINTS=1000000
PREDICT_POINTS ?= 10000000
bench-predict: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_predict.py --points $(PREDICT_POINTS)

bench-nerf: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_nerf.py

bench-splat: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_splat.py

bench-splat-render: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_splat_render.py

# Splats on lego at 100, 200, 400 and 800 px, the same views and steps: PSNR by step (issue 43).
bench-splat-resolution: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_splat_resolution.py

bench-hashgrid: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_hashgrid.py

bench-march: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_march.py

# Registration against open3d's tutorial pipeline and ICP, and small_gicp, in one run (issue 44)
bench-registration: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_registration.py

# Multiway registration: pointfield's pose graph against open3d's global_optimization, same inputs (issue 44)
bench-align: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_align.py

# scene from-rgbd against open3d's RGB-D odometry and TSDF on its 60 living-room frames, in one run (issue 44)
bench-rgbd: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_rgbd.py

bench-tsdf: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_tsdf.py

bench-geometry: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_geometry.py

# Lego's PSNR with and without opacity training, five seeds of equal steps (68 minutes for the first record)
bench-backgrounds: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_backgrounds.py

# ngp and splats scored from nearer cameras and along the turntable against a scene make scene's analytic truth
bench-near: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_near.py

# Streaming downsample of 20 M, 50 M and 200 M point LAZ files (generated once into
# ../bench-output/streaming) and Dask on a folder of scans; smaller: make bench-streaming STREAMING_SIZES=2000000,5000000
STREAMING_SIZES ?= 20000000,50000000,200000000
bench-streaming: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_streaming.py --sizes $(STREAMING_SIZES)

bench-sfm: $(BIN)/.colmap
	$(BIN)/python benchmarks/bench_sfm.py
	$(BIN)/python benchmarks/bench_sfm.py --training

bench-viewer: $(BIN)/.chromium
	$(BIN)/python benchmarks/bench_viewer.py

# What one viewer page costs the browser drawing it (software WebGL on this CPU): why --view slows training here.
bench-browser-cost: $(BIN)/.chromium
	$(BIN)/python benchmarks/bench_browser_cost.py

# TinyNeRF, the hash-grid field and splats on lego in one run (about 45 minutes on 2 cores).
bench-lego: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_lego.py

# The hash-grid field on lego at 400 x 400 for 300 s (issue 43; about 10 minutes on 2 cores).
bench-lego-400: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_lego.py --size 400 --models ngp --ngp-eval-every 100 --out bench-output/lego-400

# Mesh to signed distance grid against mesh2sdf and open3d on the ModelNet meshes (issue 46); finer: make bench-sdf SDF_SIZE=64
SDF_SIZE ?= 32
bench-sdf: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_sdf.py --size $(SDF_SIZE)

# The neural SDF field (--model sdf) against ngp, same run and budget: PSNR, mesh Chamfer, watertightness (issue 46);
# lego at 100 x 100: make bench-sdf-field SDF_FIELD_ARGS="--scene lego"
SDF_FIELD_ARGS ?=
bench-sdf-field: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_sdf_field.py $(SDF_FIELD_ARGS)

# Armadillo's points with normals to a watertight mesh against open3d's screened Poisson at depth 8 (issue 46)
bench-poisson: $(BIN)/.open3d
	$(BIN)/python benchmarks/bench_poisson.py

# Occupancy maps from the RGB-D living room against OctoMap (pyoctomap) per scan (issue 46)
bench-occupancy: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_occupancy.py

# A user's own photos with no options: from-images, splat train, nerf train, each within 10 minutes (issue 43)
bench-photos: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_photos.py

# OpenMP's waiting policy and a CPU training's speed with another program busy on a core (issue 43)
bench-threads: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_threads.py

# Ground in aerial lidar: CSF against models trained on the provider's labels (issues 44, 45)
bench-ground: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_ground.py

# The GPU path (issue 19): needs a CUDA GPU, so it is not part of `make bench`. A torch build with
# CUDA goes in first: make bench-gpu TORCH="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu126".
bench-gpu: $(BIN)/.installed
	$(BIN)/python benchmarks/bench_gpu.py

clean:
	rm -rf $(VENV) demo-output bench-output docs/_build docs/api/generated
