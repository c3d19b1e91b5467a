# Two entry points for a fresh machine (see README.md):
#   make demo   bootstrap .venv if missing, install, run the main job on the default scene
#   make test   bootstrap .venv if missing, install, run the test suite
#   make test-mpi  the MPI tier: spawned multi-rank runs, then the tests inside mpiexec -n 2
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python

.PHONY: demo test test-mpi test-slow validate-list

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

# the MPI tier (pytest marker `mpi`, left out of `make test`): the runs these tests spawn
# under mpiexec (1, 2 and 4 ranks), then the tests that run inside an mpiexec -n 2 world;
# one numba thread per rank
MPIEXEC ?= $(VENV)/bin/mpiexec
test-mpi: $(VENV)/.installed
	NUMBA_NUM_THREADS=1 $(PY) -m pytest -q -m mpi tests/test_parallel.py
	NUMBA_NUM_THREADS=1 timeout 1800 $(MPIEXEC) -n 2 $(PY) -m pytest -q -m mpi \
		-p no:cacheprovider tests/test_parallel_mpi.py

test-slow: $(VENV)/.installed
	$(PY) -m pytest -q -n 2 -m slow

validate-list: $(VENV)/.installed
	$(PY) -m validation --list
