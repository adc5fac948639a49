# `make demo` and `make test` set up .venv on first use: a fresh machine needs only Python >= 3.11.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# CPU build of PyTorch for the RL baseline (Stable-Baselines3); pinned so pip never picks a multi-GB CUDA build
	$(PY) -m pip install --quiet "torch==2.13.0"
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m envs slew --axis x --angle-deg 120 --out demo_output

test: $(STAMP)
	$(PY) -m pytest tests

bench: $(STAMP)
	$(PY) -m envs bench all

clean:
	rm -rf $(VENV) demo_output
