# The two set-up commands of the README:
#   make run    install, then run wrenchd on its embedded default (simulated PSM)
#   make test   install, then run the whole test suite (what .ci/run calls)
# Both install from requirements.lock (exact versions of every dependency); `make lock`
# refreshes it from pyproject.toml's ranges.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Real dVRK recordings used by the real-data tests; CI points this at ../shared/data/wpi-psm.
WRENCHD_WPI_DATA ?= $(abspath ../shared/data/wpi-psm)
export WRENCHD_WPI_DATA

.PHONY: install run test lock

install: $(STAMP)

# torch: the lock pins the public version `torch==2.13.0`, which PyTorch's CPU build
# `2.13.0+cpu` satisfies (PEP 440: a pin without a local label admits any). pip takes the CPU
# build from TORCH_INDEX when that index answers within a few seconds (probed first: an
# unreachable extra index would cost pip minutes of retries on every package); otherwise it
# takes 2.13.0 from wherever pip looks (PyPI: the CUDA build on Linux x86_64, CPU elsewhere).
# `make TORCH_INDEX=` skips the probe and the index.
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu
PROBE := import sys, urllib.request; urllib.request.urlopen(sys.argv[1] + "/torch/", timeout=5)

$(STAMP): pyproject.toml requirements.lock
	python3 -m venv $(VENV)
	@if [ -n "$(TORCH_INDEX)" ] && $(PY) -c '$(PROBE)' "$(TORCH_INDEX)" 2>/dev/null; then \
		echo "make: torch's CPU build from $(TORCH_INDEX)"; \
		$(PY) -m pip install --quiet --extra-index-url "$(TORCH_INDEX)" -r requirements.lock; \
	else \
		echo "make: $(or $(TORCH_INDEX),TORCH_INDEX) not used (unset or unreachable); torch as pip finds it"; \
		$(PY) -m pip install --quiet -r requirements.lock; \
	fi
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/wrenchd serve

test: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest -q

lock: $(STAMP)
	$(PY) -m pip install --quiet pip-tools
	CUSTOM_COMPILE_COMMAND="make lock" $(VENV)/bin/pip-compile --quiet --extra test --strip-extras --no-emit-index-url \
		--no-emit-find-links --output-file requirements.lock pyproject.toml
	sed -i 's/^torch==\([0-9.]*\)+cpu$$/torch==\1/' requirements.lock   # the public pin (see above)
