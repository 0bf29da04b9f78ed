# exabricks: set-up, the main job on the embedded dataset, tests, benchmarks.
# `make demo` and `make test` work on a fresh Debian/Ubuntu machine (they install
# what they need); SLURM job scripts can call the same stage commands.

PYTHON ?= python3
VENV   ?= .venv
EB      = $(VENV)/bin/exabricks
PY      = $(VENV)/bin/python
OUT    ?= out
DATA    = exabricks/data/gerris-plume
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: setup system-deps demo lint docs wheel test test-slow test-suites fuzz test-slurm test-gauge kernel-resources test-all bench bench-large gallery clean browser-deps

system-deps:
	@if ! ls /etc/OpenCL/vendors/*.icd >/dev/null 2>&1; then \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq pocl-opencl-icd ocl-icd-libopencl1 >/dev/null; \
	fi

# The package with the dev extra (tests, linter, the site's tools, benchmarks' peers; about 2.1 GB): setup, test.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e '.[dev]'
	touch $@

# The package with its runtime dependencies only (about 0.8 GB): what the demo needs.
$(VENV)/.installed-run: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e .
	touch $@

setup: system-deps $(VENV)/.installed

# The main job: the embedded Gerris plume through every stage.
$(OUT)/cells.npz: $(VENV)/.installed-run
	@mkdir -p $(OUT)
	$(EB) ingest $(DATA)/plume7-1.cells -o $@

$(OUT)/bricks.npz: $(OUT)/cells.npz
	$(EB) brick $< -o $@

$(OUT)/regions.npz: $(OUT)/bricks.npz
	$(EB) regions $< -o $@

$(OUT)/bvh.npz: $(OUT)/regions.npz
	$(EB) bvh $< -o $@

# The hot core as an iso-surface (T = 0.45, with ambient occlusion and a little
# specular) inside the translucent volume of T, on a dark background. 64 occlusion
# rays per hit and 4 samples per pixel: the occlusion's grain falls below the
# volume's own jitter noise (docs/benchmarks-render.md, "Iso-surface normals").
# `devices --warm` first builds the kernels of this picture and of a default render
# (exabricks/warm.py), so that neither waits for a compile afterwards.
$(OUT)/plume.png: $(OUT)/bvh.npz
	$(EB) devices --warm
	$(EB) -v render $(OUT)/bricks.npz $(OUT)/regions.npz $(OUT)/bvh.npz -o $@ \
	  --field T --camera $(DATA)/camera.json \
	  --colormap inferno --range -0.1 0.6 --opacity 0,0,0.1,0.18,0.25,0.3,0.35,0.4 \
	  --iso 0.45 --iso-color 0.95,0.95,1 --specular 0.3 --ao-samples 64 --spp 4 \
	  --background 0.05,0.05,0.08

demo: system-deps $(OUT)/plume.png
	@echo "image: $(OUT)/plume.png"

# ruff (its rules in pyproject.toml) over the package, the tests, the benchmarks,
# the users' workflows and the picture scripts.
lint: setup
	$(VENV)/bin/ruff check exabricks tests benchmarks workflows docs/pictures docs/hooks.py

# The documentation site from docs/ into site/ (mkdocs.yml; MkDocs in strict mode: a
# warning, a broken link or anchor, a page outside the nav fails the build). The
# reference pages are generated from the code: the command line from click, the
# render options from exabricks/scene/options.py (docs/hooks.py), the Python API
# from the docstrings (mkdocstrings). About 10 s.
docs: setup
	$(PY) -m mkdocs build --strict --site-dir site

# A wheel of the package into $(DIST) (exabricks is not on PyPI): the package, its
# kernels and the embedded plume; `pip install "$$(ls dist/exabricks-*.whl)[cpu]"`
# installs it anywhere (docs/install.md). tests/device/test_runtime.py builds it with
# this target, installs it into a fresh venv with the cpu extra and renders the demo.
DIST ?= dist
wheel: $(VENV)/.installed-run
	rm -f $(DIST)/exabricks-*.whl
	$(PY) -m pip wheel --no-deps -q -w $(DIST) .
	@ls $(DIST)/exabricks-*.whl

# Test processes (pytest-xdist), a file's tests in one of them: PoCL's kernel
# builds and numba's compiles of a fresh checkout spread over the cores.
WORKERS ?= 2

# The fast suite (minutes): everything but the `slow` tests; each fuzzer runs a
# few examples (EXABRICKS_FUZZ_EXAMPLES, default in tests/conftest.py).
# The fast suite: every test under no marker (the fuzzers run in `make fuzz`).
test: setup
	$(PY) -m pytest -q -n $(WORKERS) --dist loadfile -m "not slow and not slurm and not gauge and not fuzz"

# Headless Chromium and its driver for the viewer's browser tests (tests/viewer/test_view.py).
browser-deps:
	@if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null; \
	fi

# The slow tests (real datasets end to end, random layouts, no-JIT runs, the viewer
# in a real browser).
test-slow: setup browser-deps
	$(PY) -m pytest -q -n $(WORKERS) --dist loadfile -m "slow"

# The fast and slow suites in one run (what CI runs: no test process waits idle
# at the end of one suite for the other to finish its last file), less the
# fuzzers, which `make fuzz` runs with many examples.
test-suites: setup browser-deps
	$(PY) -m pytest -q -n $(WORKERS) --dist loadfile -m "not slurm and not gauge and not fuzz"

# The fuzzers with many examples each: 80, which keeps CI within its 45 minutes on
# two cores (each of tests/cli/test_fuzz.py's ten fuzzers takes about 1 s an example).
fuzz: setup
	EXABRICKS_FUZZ_EXAMPLES=80 $(PY) -m pytest -q -n $(WORKERS) -m "fuzz"

# The SLURM workflows on a one-node cluster on this machine (workflows/slurm/up.sh:
# Debian's slurm-wlm and munge, started by hand; root, or sudo).
test-slurm: setup
	$(SUDO) workflows/slurm/up.sh
	EXABRICKS_SLURM=1 $(PY) -m pytest -q -m "slurm"

# The kernels' NVIDIA registers, stack and spills against their budgets, offline
# (../shared/tools/gpu-proxy, set up once by its setup.sh; benchmarks/gpu_gauge.py).
test-gauge: setup
	$(PY) -m pytest -q -m "gauge"

# The same figures as a table in docs/benchmarks.md.
kernel-resources: setup
	$(PY) -m benchmarks.gpu_gauge --write-docs

# What CI runs: the linter, the documentation site (warnings as errors) and every suite.
test-all: lint docs test-suites fuzz test-gauge test-slurm

# Every benchmark, in order, each replacing its own "## section" of docs/benchmarks.md
# (median of 5 runs after a warm-up; figures are only meaningful on a quiet machine).
# The generated inputs under bench-data/ (make_big.py's 512^3 volume as 23.6 M AMR
# cells and as an AMReX plotfile, and its 20.6 M-cell octree-like thin shells) are
# made on first use by the scripts.
bench: setup
	@# ingest: cells/s of the 23 M-cell ExaJet and AMReX inputs and plt00020
	$(PY) -m benchmarks.bench_ingest --write-docs
	@# preprocessing: the four stage commands per dataset (time, peak memory, Table 1, bytes)
	$(PY) -m benchmarks.bench_preprocess --write-docs
	@# merged regions against the paper's exact ones, bytes per cell and frames
	$(PY) -m benchmarks.bench_merge --write-docs
	@# render: the OpenCL renderer on the four real datasets and the thin shells, both walks, both sample paths
	$(PY) -m benchmarks.bench_render --write-docs
	@# loading: a render command's cost before its first sample, against reading its files
	$(PY) -m benchmarks.bench_load --write-docs
	@# kernel builds: the first frame of each program variant with empty PoCL caches
	$(PY) -m benchmarks.bench_compile --write-docs
	@# where a frame's time goes: perf samples by kernel function (skipped without perf)
	@if command -v perf >/dev/null; then $(PY) -m benchmarks.profile_render --write-docs; fi
	@# the same for bench_peers' frame (shading none), on which the targets are measured
	@if command -v perf >/dev/null; then $(PY) -m benchmarks.profile_render --only amrex,athena,gerris --view peers --write-docs; fi
	@# peers: exabricks vs yt, VTK, per-sample cell location and the uniform-grid ceiling (1024², all datasets)
	$(PY) -m benchmarks.bench_peers --json bench-data/peers.json
	@# render modes: iso-surfaces, slices, clipping, AO, layers, gradients (Gerris, AMReX)
	$(PY) -m benchmarks.bench_modes --write-docs
	@# reconstructions (basis, nearest, vertex) and level of detail (speed vs error)
	$(PY) -m benchmarks.bench_reconstructions --write-docs
	@# rendering under a memory budget: thin shells (whole frames, bands), Gerris posters
	$(PY) -m benchmarks.bench_budget --write-docs
	@# domains kept across samples, bands and frames, and prefetched (make_big.py's layouts)
	$(PY) -m benchmarks.bench_domain_cache --write-docs
	@# coherent rays: how full packets of 2x2 and 4x2 rays sharing one region walk would be
	$(PY) -m benchmarks.bench_lane_fill --write-docs
	@# pre-integrated transfer functions against the midpoint rule, float64, at equal sample counts
	$(PY) -m benchmarks.bench_preintegration --picture docs/images/preintegration-peaks.png --write-docs
	@# shadows: the cached transmittance against the headlight and traced shadow rays, under a budget, in the viewer
	$(PY) -m benchmarks.bench_shadows --write-docs
	$(PY) -m benchmarks.bench_shadow_domains --write-docs
	$(PY) -m benchmarks.bench_view_shadows --write-docs

# The thin shells at 204 M cells: every stage and budgeted renders, builders by
# pieces, and MPI renders with 1, 2 and 4 ranks beside the 20.6 M-cell shells and
# the 512³ volume (about 60 min, 25 GB of disk under bench-data/; the MPI orbit
# runs when a SLURM cluster answers, workflows/slurm/up.sh).
bench-large: setup
	$(PY) -m benchmarks.bench_large --write-docs
	$(PY) -m benchmarks.bench_pieces --pieces 4 --only shell --cells bench-data/large/shell2944/cells.npz --write-docs
	$(PY) -m benchmarks.bench_mpi --only big,shell --ranks 1,2,4 --large bench-data/large/shell2944 --write-docs

# Every image of docs/gallery.md, with the commands that make them.
gallery: setup
	$(PY) -m benchmarks.gallery

clean:
	rm -rf $(OUT)
