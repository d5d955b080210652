# hub-envs — every target installs what it needs first, so on a fresh clone one command is enough.
#
# Two venvs, the two ends of the supported range, both tested by `make test`:
#   .venv         the newest Python >= 3.12 on this machine (3.13, else 3.12) with the newest lerobot in
#                 range (0.6.x: huggingface_hub 1.x, draccus 0.11); used by demo and bench too. With no
#                 such Python it falls back to Python 3.11 + lerobot 0.4.4 and says so.
#   .venv-compat  Python 3.11, lerobot 0.4.4, huggingface_hub 0.35, draccus 0.10 (constraints/compat.txt).
PYTHON_NEW    ?= $(shell sh scripts/find-python 3.13 3.12)
PYTHON_COMPAT ?= $(shell sh scripts/find-python 3.11)
VENV          := .venv
VENV_COMPAT   := .venv-compat
PY            := $(VENV)/bin/python
PY_COMPAT     := $(VENV_COMPAT)/bin/python
COMPAT        := constraints/compat.txt
export HF_HUB_DISABLE_TELEMETRY := 1

ifeq ($(strip $(PYTHON_NEW)),)
NEW_PYTHON      := $(PYTHON_COMPAT)
NEW_CONSTRAINTS := $(COMPAT)
FALLBACK        := 1
else
NEW_PYTHON      := $(PYTHON_NEW)
NEW_CONSTRAINTS :=
FALLBACK        :=
endif

.PHONY: install install-compat lint test demo bench train-long clean

install: $(VENV)/.install-stamp
install-compat: $(VENV_COMPAT)/.install-stamp

# Rebuilt only when the dependency lists change. uv resolves several times faster than pip; lerobot
# brings torch with its own pin. pybullet has no wheel for Python >= 3.12: uv builds it once (minutes)
# and keeps the wheel in its cache.
$(VENV)/.install-stamp: pyproject.toml $(COMPAT) scripts/make-venv
ifneq ($(FALLBACK),)
	@echo "make install: no Python >= 3.12 found (looked for python3.13, python3.12 on PATH and in pyenv);" \
	      "falling back to Python 3.11 + lerobot 0.4.4 in $(VENV)."
endif
	sh scripts/make-venv $(VENV) "$(NEW_PYTHON)" "$(NEW_CONSTRAINTS)"

$(VENV_COMPAT)/.install-stamp: pyproject.toml $(COMPAT) scripts/make-venv
	sh scripts/make-venv $(VENV_COMPAT) "$(PYTHON_COMPAT)" "$(COMPAT)"

SOURCES := hub_envs tests benchmarks envs plugins

# ruff: lint (pyflakes, pycodestyle, import order, pyupgrade, bugbear) and the formatter's verdict; import-linter: the
# architecture's layers, independences and no import circle (the contracts in pyproject.toml), on this checkout;
# mkdocs: the docs site (mkdocs.yml) in strict mode, into site/: a broken link or anchor, or a docstring its
# API reference cannot parse, fails.
lint: install
	$(VENV)/bin/ruff check $(SOURCES) scripts/docs_hooks.py scripts/docs_griffe.py
	$(VENV)/bin/ruff format --check $(SOURCES) scripts/docs_hooks.py scripts/docs_griffe.py
	PYTHONPATH=$(CURDIR) $(VENV)/bin/lint-imports
	PYTHONPATH=$(CURDIR) $(VENV)/bin/mkdocs build --strict

# The whole suite in both venvs (one leg when .venv fell back to the compat stack); says which leg failed.
ifeq ($(FALLBACK),)
test: install install-compat lint
	sh scripts/test-legs venv=$(PY) venv-compat=$(PY_COMPAT)
else
test: install lint
	sh scripts/test-legs venv=$(PY)
endif

# SERVE=1: keep the loopback Hub and its web page up after the demo, until Ctrl-C.
demo: install
	$(PY) -m hub_envs.demo $(if $(SERVE),--serve)

bench: install
	$(PY) -m benchmarks.run

# Train LeRobot's ACT on published envs' random-action datasets and evaluate it (CPU, ~1 h;
# flags: make train-long TRAIN_LONG_ARGS="--envs reach --steps 2000").
train-long: install
	$(PY) -m benchmarks.train_long $(TRAIN_LONG_ARGS)

clean:
	rm -rf $(VENV) $(VENV_COMPAT) .pytest_cache .hypothesis .test-results benchmarks/out demo-out site
