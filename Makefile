# `make demo` and `make test` set up .venv on first use: a fresh machine needs only Python >= 3.11.
#   make demo   light install (the package and matplotlib), then one closed-loop 120° slew with plots
#   make test   the dev extra (pytest, SB3 + PyTorch, Ray) and the whole test suite
# Both first compile the numba kernels in parallel processes (`startracker-gym compile`, about a minute on 2 cores on
# a fresh machine or after a kernel edit, a few seconds when they are cached; the demo only the default env's).
#   make bench  every benchmark script of this checkout (light install)
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
CLI := $(VENV)/bin/startracker-gym
BASE := $(VENV)/.base
DEMO := $(VENV)/.demo-installed
DEV := $(VENV)/.dev-installed
# PyTorch for the RL tests (Stable-Baselines3). A version pin does not choose the build: from PyPI on Linux x86-64
# this wheel pulls the CUDA libraries (several GB). For the CPU-only build (~200 MB) run
#   make test TORCH_PIP_ARGS="--index-url https://download.pytorch.org/whl/cpu"
# (on the project's CI machines the pin already resolves to a local CPU wheel).
TORCH_PIP_ARGS ?=

.PHONY: demo test bench clean

$(BASE):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	touch $(BASE)

$(DEMO): pyproject.toml $(BASE)
	$(PY) -m pip install --quiet -e ".[plots]"
	touch $(DEMO)

$(DEV): pyproject.toml $(BASE)
	$(PY) -m pip install --quiet "torch==2.13.0" $(TORCH_PIP_ARGS)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(DEV) $(DEMO)

demo: $(DEMO)
	$(CLI) compile --default-only
	$(CLI) slew --axis x --angle-deg 120 --out demo_output --force

test: $(DEV)
	$(CLI) compile
	$(PY) -m pytest tests

bench: $(DEMO)
	$(CLI) bench all

clean:
	rm -rf $(VENV) demo_output
