# Two entry points for a fresh machine (see README.md):
#   make demo   bootstrap .venv if missing, install, run the main job on the default scene
#   make test   bootstrap .venv if missing, install, run the test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python

.PHONY: demo test test-slow validate-list

$(VENV)/.installed: pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@touch $@

demo: $(VENV)/.installed
	$(VENV)/bin/upscale demo

# two pytest workers, one per core (pytest-xdist): the suite is mostly single-threaded
# Python, LAMMPS and numba compilation
test: $(VENV)/.installed
	$(PY) -m pytest -q -n 2

test-slow: $(VENV)/.installed
	$(PY) -m pytest -q -n 2 -m slow

validate-list: $(VENV)/.installed
	$(PY) -m validation --list
