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

# torch==2.13.0+cpu in the lock is the CPU build that this project's machines carry as a
# local wheel (pip's find-links); the registry's own 2.13.0 is a multi-GB CUDA build.
$(STAMP): pyproject.toml requirements.lock
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements.lock
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
