# mcdenoise — developer and user entry points.
#   make demo    install, then run the demo experiment (what accuracy costs in time: four
#                scenes, 1-64 spp, every available method) -> demo-out/report.html
#   make test    install, then run the test suite (slow and GPU tests are skipped)
#   make test-fast  the fast tier (under 2 minutes on 2 cores): the suite less the tests marked
#                heavy in tests/heavy_tests.txt; PKG=filters runs tests/filters only
#   make wheel-check  the package as users install it: build the wheel, install it into a
#                fresh venv outside the checkout, run `methods` and a denoise (.ci/wheel_check)
# Everything installs into a local virtual environment (.venv); torch is pinned to the CPU
# build first so no resolver pulls the multi-GB CUDA packages.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  ?= torch==2.13.0
STAMP  := $(VENV)/.mcdenoise-installed

.PHONY: install system-deps browser-deps test test-fast test-all wheel-check lint format bench demo samples data clean

install: $(STAMP)

$(STAMP): pyproject.toml setup.py
	@$(MAKE) --no-print-directory system-deps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q $(TORCH)
	@# PYTHONWARNINGS: setuptools' editable install says, as a UserWarning block, that a folder
	@# named like the package may shadow it; that is the point of an editable install here
	PYTHONWARNINGS=ignore::UserWarning $(BIN)/python -m pip install -q -e '.[all]'
	@touch $@

# Debian's libllvm19 makes Mitsuba's fast llvm_ad_rgb variant work (3-6x scalar_rgb); run by
# `make install` (once per install) and by .ci/run; without root or apt it prints a note.
system-deps:
	@if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  apt-get install -y -q libllvm19 >/dev/null 2>&1 || \
	  { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libllvm19 >/dev/null 2>&1; } || \
	  echo "note: libllvm19 not installed; Mitsuba falls back to scalar_rgb"; \
	else echo "note: not root or no apt-get; skipping libllvm19 (Mitsuba uses scalar_rgb)"; fi

# Debian's chromium runs the report viewer's browser tests (skipped without it, failed under
# CI=true); only the tests need it, so `make demo` does not install it.
browser-deps:
	@command -v chromium >/dev/null 2>&1 || \
	if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  apt-get install -y -q chromium >/dev/null 2>&1 || \
	  { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1; } || \
	  echo "note: chromium not installed; the report viewer's browser tests are skipped"; \
	else echo "note: not root or no apt-get; no chromium: the browser tests are skipped"; fi

test: install browser-deps
	$(BIN)/python -m pytest -q

# The tier to run while changing code (docs/development.md#tests): `make test` is the full
# default suite (about 7.5 minutes on 2 cores); this one deselects the tests named in
# tests/heavy_tests.txt (subprocesses, training runs, experiments end to end, naive reference
# loops, every method on every sample, Mitsuba renders) and keeps every area's others.
# PKG=io (a folder of tests/) runs that area only.
PKG ?=
test-fast: install
	$(BIN)/python -m pytest -q -m "not heavy" --durations=5 $(if $(PKG),tests/$(PKG))

# Slow tests too (long renders, full-size memory checks).
test-all: install browser-deps
	MCDENOISE_SLOW=1 $(BIN)/python -m pytest -q

# The wheel a user's `pip install .` builds, installed into a fresh venv outside the checkout
# (nothing downloaded: dependencies come from $(VENV)); the editable install hides a package
# left out of the wheel. About 10 s.
wheel-check: install
	.ci/wheel_check $(BIN)/python

lint: install
	$(BIN)/ruff check mcdenoise cli tests benchmarks data setup.py
	$(BIN)/ruff format --check mcdenoise cli tests benchmarks data setup.py

format: install
	$(BIN)/ruff format mcdenoise cli tests benchmarks data setup.py
	$(BIN)/ruff check --fix mcdenoise cli tests benchmarks data setup.py

bench: install
	$(BIN)/python benchmarks/bench_quality.py
	$(BIN)/python benchmarks/bench_filters.py

# The built-in experiment data/experiments/demo.toml: four curated scenes at 128x128, 1-64 spp,
# every installed method; renders into $(DEMO_OUT)/data once, and a re-run reuses the images
# and every finished unit (delete $(DEMO_OUT)/work to time the denoisers again). The first
# line printed and the last (mcdenoise's own "report: ...") say where the report is.
DEMO_OUT ?= demo-out
demo: install
	@echo "demo: experiment data/experiments/demo.toml -> report: $(DEMO_OUT)/report.html"
	$(BIN)/mcdenoise experiment data/experiments/demo.toml -o $(DEMO_OUT)

# Re-render the shipped sample data (needs the 'render' extra: Mitsuba 3): the scene specs
# data/scenes/samples/*.toml through mcdenoise render into $(SAMPLES_WORK) (an ordinary render
# folder; re-running skips finished images), then written in the layout of data/samples
# (<scene>_spp4.exr, <scene>_spp16.exr, ref/<scene>.exr) by --samples-out. data/samples/README.md.
SAMPLES_OUT  ?= data/samples
SAMPLES_WORK ?= build/samples-render
samples: install system-deps
	$(BIN)/mcdenoise render data/scenes/samples --no-halves -o $(SAMPLES_WORK) --res 128 --spp 4,16 \
	  --ref-spp 16384 --samples-out $(SAMPLES_OUT)

# A small training set (gitignored): the curated specs in data/scenes plus DATA_RANDOM
# procedural scenes, 128x128, noisy 4/16/64 spp, 1024 spp references (mcdenoise render;
# re-running skips finished images). Size and time: docs/rendering.md.
DATA_OUT    ?= data/generated/train
DATA_RANDOM ?= 12
DATA_SEED   ?= 0
data: install system-deps
	$(BIN)/mcdenoise render data/scenes --random $(DATA_RANDOM) --seed $(DATA_SEED) \
	  -o $(DATA_OUT) --res 128 --spp 4,16,64 --ref-spp 1024

clean:
	rm -rf $(DEMO_OUT) .pytest_cache .ruff_cache build *.egg-info
