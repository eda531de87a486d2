# make demo: set up .venv and run the main job on the simulated robot.
# make test: set up .venv and run the whole test suite.
# make lint: ruff over the whole tree (.ci/run runs test, then lint).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,ros2,sim,plots,franka,franky]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/iem demo

# one BLAS thread for the suite, as the iem command takes it (deploy/cli.py): its small
# solves only contend for the two cores otherwise
test: $(STAMP)
	OPENBLAS_NUM_THREADS=$${OPENBLAS_NUM_THREADS:-1} $(PY) -m pytest

bench: $(STAMP)
	$(VENV)/bin/iem bench sim
	$(VENV)/bin/iem bench paper --out out/bench-paper
	$(VENV)/bin/iem bench bridge
	$(VENV)/bin/iem bench e2e

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
