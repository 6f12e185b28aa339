# Two commands do all set-up: `make test` and `make demo` (see README.md).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test test-slow test-all test-cuda demo weights ablations benchmarks clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# torch first and pinned: an unpinned torch pulls the multi-GB CUDA build. TORCH_INDEX picks
	# the index it comes from (e.g. https://download.pytorch.org/whl/cpu for the CPU-only wheel on
	# Linux, where PyPI's torch is the CUDA build).
	$(BIN)/pip install --quiet torch==2.13.0 $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	$(BIN)/pip install --quiet -e '.[test]'
	# LPIPS linear weights ship in the lpips package; its torchvision dependency has no CPU build.
	$(BIN)/pip install --quiet --no-deps lpips==0.1.4
	touch $(STAMP)

# One test worker per core (pytest-xdist; tests/conftest.py gives each worker one thread).
TEST_WORKERS ?= auto

test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS)

test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow

test-all: $(STAMP)
	$(BIN)/python -m pytest -m ''

# The GPU path (gsplat must be installed: docs/performance.md, "GPU"); skipped without CUDA.
test-cuda: $(STAMP)
	$(BIN)/python -m pytest -m cuda -rs

demo: $(STAMP)
	$(BIN)/lumos3d restore examples/lowlight-buu -o out/demo/scene.ply
	@echo "results in out/demo/: scene.ply, cameras.json, colmap/, restored/, contact_sheet.png, preview.glb, summary.json"

# Retrain the bundled models from ../shared/data/scenes (docs/model-card.md; hours on a CPU).
weights: $(STAMP)
	$(BIN)/lumos3d train configs/default-teacher.yaml
	$(BIN)/lumos3d train configs/default-low-light.yaml
	$(BIN)/lumos3d train configs/default-over-exposure.yaml
	# both modes ship with the appearance operator: a head-only stage on SICE brackets (issue 15),
	# the step with the best held-out bracket PSNR (select: bracket_psnr)
	$(BIN)/lumos3d train configs/operator-head-low-light.yaml
	$(BIN)/lumos3d convert runs/operator-head-low-light/selected.safetensors -o src/lumos3d_cli/weights/lumos3d-low-light.safetensors --dtype float16
	# then the mixed-batch stage over the whole low-light network (multi-view scenes with the full
	# objective + bracket pairs); validate_at_start: it ships its start unless a step beats it on the
	# held-out brackets (none did in its run: model-card.md)
	$(BIN)/lumos3d train configs/operator-low-light.yaml
	$(BIN)/lumos3d convert runs/operator-low-light/selected.safetensors -o src/lumos3d_cli/weights/lumos3d-low-light.safetensors --dtype float16
	$(BIN)/lumos3d train configs/operator-head-over-exposure.yaml
	$(BIN)/lumos3d convert runs/operator-head-over-exposure/selected.safetensors -o src/lumos3d_cli/weights/lumos3d-over-exposure.safetensors --dtype float16

# Train the ablation students the model card reports (after `make weights`; hours on a CPU) and
# rewrite its ablation table.
ablations: $(STAMP)
	$(BIN)/python benchmarks/ablations.py --train

benchmarks: $(STAMP)
	$(BIN)/python benchmarks/rasterizer.py
	$(BIN)/python benchmarks/model.py
	$(BIN)/python benchmarks/train.py
	$(BIN)/python benchmarks/presets.py

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache
