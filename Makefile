# The two set-up commands of the README:
#   make run    install, then run wrenchd on its embedded default (simulated PSM)
#   make test   install, then run the whole test suite (what .ci/run calls)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Real dVRK recordings used by some tests; CI points this at ../shared/data/wpi-psm.
WRENCHD_WPI_DATA ?= $(abspath ../shared/data/wpi-psm)
export WRENCHD_WPI_DATA

.PHONY: install run test

install: $(STAMP)

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	# torch first, pinned: the package index here carries the 2.13.0 CPU build, and asking
	# for it explicitly keeps pip from resolving a multi-GB CUDA build.
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/wrenchd serve

test: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m pytest -q
