# mcdenoise — developer and user entry points.
#   make demo    install, then denoise the sample renders with every available method and
#                write an HTML report (demo-out/report/report.html)
#   make test    install, then run the test suite (slow and GPU tests are skipped)
# Everything installs into a local virtual environment (.venv); torch is pinned to the CPU
# build first so no resolver pulls the multi-GB CUDA packages.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
TORCH  ?= torch==2.13.0
STAMP  := $(VENV)/.mcdenoise-installed

.PHONY: install system-deps test test-all lint format bench demo samples data clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory system-deps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q $(TORCH)
	$(BIN)/python -m pip install -q -e '.[all]'
	@touch $@

# Debian's libllvm19 makes Mitsuba's fast llvm_ad_rgb variant work (3-6x scalar_rgb); run by
# `make install` (once per install) and by .ci/run; without root or apt it prints a note.
system-deps:
	@if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  apt-get install -y -q libllvm19 >/dev/null 2>&1 || \
	  { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libllvm19 >/dev/null 2>&1; } || \
	  echo "note: libllvm19 not installed; Mitsuba falls back to scalar_rgb"; \
	else echo "note: not root or no apt-get; skipping libllvm19 (Mitsuba uses scalar_rgb)"; fi

test: install
	$(BIN)/python -m pytest -q

# Slow tests too (long renders, full-size memory checks).
test-all: install
	MCDENOISE_SLOW=1 $(BIN)/python -m pytest -q

lint: install
	$(BIN)/ruff check mcdenoise cli tests benchmarks data
	$(BIN)/ruff format --check mcdenoise cli tests benchmarks data

format: install
	$(BIN)/ruff format mcdenoise cli tests benchmarks data
	$(BIN)/ruff check --fix mcdenoise cli tests benchmarks data

bench: install
	$(BIN)/python benchmarks/bench_quality.py
	$(BIN)/python benchmarks/bench_filters.py

DEMO_OUT ?= demo-out
demo: install
	@rm -rf $(DEMO_OUT)/denoised
	$(BIN)/mcdenoise denoise data/samples --method all -o $(DEMO_OUT)/denoised
	$(BIN)/mcdenoise eval --ref data/samples/ref $(DEMO_OUT)/denoised -o $(DEMO_OUT)/report
	@echo "report: $(DEMO_OUT)/report/report.html"

# Re-render the shipped sample data (needs the 'render' extra: Mitsuba 3).
samples: install system-deps
	$(BIN)/python data/make_samples.py --out data/samples

# A small training set (gitignored): the curated specs in data/scenes plus DATA_RANDOM
# procedural scenes, 128x128, noisy 4/16/64 spp, 1024 spp references (mcdenoise render;
# re-running skips finished images). Size and time: README, "Rendering data sets".
DATA_OUT    ?= data/generated/train
DATA_RANDOM ?= 12
DATA_SEED   ?= 0
data: install system-deps
	$(BIN)/mcdenoise render data/scenes --random $(DATA_RANDOM) --seed $(DATA_SEED) \
	  -o $(DATA_OUT) --res 128 --spp 4,16,64 --ref-spp 1024

clean:
	rm -rf $(DEMO_OUT) .pytest_cache .ruff_cache build *.egg-info
