# `make run` and `make test` each set up .venv/ themselves (fresh clone friendly).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PRECOMPILED := $(VENV)/.precompiled
DATA := ../shared/data

.PHONY: setup test run bench model clean

setup: $(PRECOMPILED)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

# Ahead of time, in two processes at once: the kernels of run and sweep, and those of every model kind's
# fit and inverse and of the diagnosis, compiled into numba's cache after install and after their
# sources change, so the first run, sweep or test after either compiles nothing.
KERNELS := $(wildcard controller/laws/*.py controller/alarms.py controller/sweep/simulate.py plant_sim/kernel.py models/*.py models/diagnose/*.py)
# Numba checks a cached kernel against its own file only, not the files of the kernels it inlines:
# the caches are cleared first, so an edit anywhere in KERNELS is never run as stale machine code.
$(PRECOMPILED): $(STAMP) $(KERNELS)
	find controller models plant_sim -path '*/__pycache__/*' \( -name '*.nbi' -o -name '*.nbc' \) -delete
	$(PY) -m controller.precompile --models & models=$$!; $(PY) -m controller.precompile && wait $$models
	touch $(PRECOMPILED)

# Two workers: the real-time tests (tests/conftest.py's REALTIME_MODULES) one after the other on one of
# them, the CPU-bound tests on both. `-n0` runs everything in one process.
test: setup
	$(PY) -m pytest -q -n 2 --dist loadgroup

# The main job: a 20 s closed-loop run of a breath profile with ff+kf on the embedded simulated
# valve (valve_dynamics, transport_delay and sensor noise on; config/run.toml). The simulated valve
# is the bench valve's twin (pi-asym of the identification recording, config/valves/bench/), a
# different model kind from the feedforward's PI (config/valve_model.json): no controller against
# its own model.
run: setup
	mkdir -p out
	$(VENV)/bin/valvectl run --config config/run.toml --json out/run.json --plot out/run.png --report out/run

# The simulated valve's default forward model: the PI fitted on the identification recording.
model: setup
	$(VENV)/bin/valvectl fit $(DATA)/bench_identification.csv --model pi -o config/valve_model.json

bench: setup
	for b in bench/bench_*.py; do echo "== $$b"; OPENBLAS_NUM_THREADS=1 $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache
