# hub-envs — every target installs what it needs first, so on a fresh clone one command is enough.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.install-stamp
export HF_HUB_DISABLE_TELEMETRY := 1

.PHONY: install test demo bench train-long clean

install: $(STAMP)

# Re-run only when the dependency list changes. uv (installed into the venv from PyPI) resolves the
# same pins as pip, several times faster; lerobot==0.4.4 brings torch with its own pin.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check uv
	$(VENV)/bin/uv pip install --quiet --python $(PY) -e ".[dev]"
	touch $(STAMP)

test: install
	$(PY) -m pytest -q tests

demo: install
	$(PY) -m hub_envs.demo

bench: install
	$(PY) -m benchmarks.run

# Train LeRobot's ACT on published envs' random-action datasets and evaluate it (CPU, ~1 h;
# flags: make train-long TRAIN_LONG_ARGS="--envs reach --steps 2000").
train-long: install
	$(PY) -m benchmarks.train_long $(TRAIN_LONG_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis benchmarks/out demo-out
