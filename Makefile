# The README's two commands: `make demo` and `make test`. Both install into ./.venv when it is
# missing or older than pyproject.toml: the demo only the robot-side base install (no torch,
# no test tools), the tests every extra on top of it.
PYTHON ?= python3
TORCH_VERSION ?= 2.13.0
VENV := .venv
BIN := $(VENV)/bin
BASE := $(VENV)/.installed-base
STAMP := $(VENV)/.installed

# the tests in parallel, one worker per core (pytest-xdist): docs/install.md has their time
# beside one process's
TEST_WORKERS ?= auto

.PHONY: demo test lint bench bundle clean arm-check

$(BASE): pyproject.toml Makefile constraints/robot.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints/robot.txt -e .
	touch $(BASE)

$(STAMP): $(BASE)
	$(BIN)/pip install --quiet torch==$(TORCH_VERSION)
	$(BIN)/pip install --quiet -c constraints/robot.txt -e '.[oak,train,dev,openvino,fleet,ros2,band]'
	touch $(STAMP)

demo: $(BASE)
	$(BIN)/edge-depth demo

test: $(STAMP)
	$(BIN)/ruff check edge calibration tools tests experiments
	$(BIN)/mypy
	$(BIN)/python -m pytest -n $(TEST_WORKERS)

# the robot-side install on emulated aarch64 CPUs (QEMU: Cortex-A76, Cortex-A72) against this
# host's results; root, a cached Debian arm64 root (.ci/arm_check.sh says what and how long)
arm-check: $(BASE)
	bash .ci/arm_check.sh

bench: $(STAMP)
	mkdir -p out
	$(BIN)/python tools/bench.py --runs 3 --json out/bench.json --markdown out/bench.md

# rebuild the shipped bundle from the shipped checkpoint (export, then int8 quantization
# calibrated on 8 rig + 8 things frames from training seeds, evaluated on the test split,
# then the LiDAR selection fitted on 260 things pairs no shipped stage trained on,
# or with SELECTIONS=carry kept from the bundle it replaces)
CHECKPOINT ?= edge/models/sparse_stereo.pt
QUANTIZE_FLAGS ?=# e.g. --min-gain -1 on a host without VNNI, where int8 is never faster
SELECTIONS ?= fit# fit: on data/things_select; carry: the replaced bundle's (stage 16 shipped so)
ITERS ?= 4# the iterations the bundle is quantized and its selections fitted at
RUN_ITERS ?= 3# the bundle's default iterations, what it runs at (model.json's default_iters)
bundle: $(STAMP)
	case "$(SELECTIONS)" in fit|carry) ;; *) echo "SELECTIONS=$(SELECTIONS): fit or carry" >&2; exit 2;; esac
	test -d data/test16 || $(BIN)/edge-depth synth --out data/test16 --count 20 --seed 1000000 --lidar beams16
	test -d data/calib_mix || ($(BIN)/edge-depth synth --out data/calib_mix --count 8 --seed 500000 \
	  && $(BIN)/edge-depth synth --world things --scene-folders --out data/calib_mix --count 8 --seed 900000)
	mkdir -p out && rm -f out/replaced-model.json && (test ! -f edge/models/default/model.json \
	  || cp edge/models/default/model.json out/replaced-model.json)
	rm -rf edge/models/default
	$(BIN)/python tools/export.py $(CHECKPOINT) --out edge/models/default --size 640x400 \
	  --iters $(RUN_ITERS)
	$(BIN)/python tools/quantize.py edge/models/default --calib data/calib_mix --eval data/test16 \
	  --iters $(ITERS) $(QUANTIZE_FLAGS)
	if [ "$(SELECTIONS)" = carry ]; then \
	  $(BIN)/python tools/carry_selections.py out/replaced-model.json edge/models/default; \
	else \
	  (test -d data/things_select || $(BIN)/edge-depth synth --world things \
	    --out data/things_select --count 260 --seed 400000 --workers 2) \
	  && $(BIN)/python tools/fit_select.py edge/models/default --data data/things_select; \
	fi

clean:
	rm -rf $(VENV) out
