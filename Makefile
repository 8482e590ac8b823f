# Set-up is two commands on a fresh machine: `make demo` and `make test` (each installs first).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# `make install GPU=1` adds the `cuda` extra (jax[cuda12], same JAX version); its own stamp
# also marks the CPU one done, so a later `make test` does not reinstall.
ifeq ($(GPU),1)
EXTRAS := dev,cuda
STAMP := $(VENV)/.installed-gpu
else
EXTRAS := dev
STAMP := $(VENV)/.installed
endif

.PHONY: install demo test test-slow lint bench clean

install: $(STAMP)

# Reinstall only when the requirements or their pins change: the stamp makes `make install`
# idempotent. pyproject.toml holds ranges; constraints.txt the exact versions installed here.
# pip installs without compiling the bytecode (one file at a time, half its time on two cores),
# then compileall writes it on every core: the machines here set PYTHONDONTWRITEBYTECODE, so
# without it every test process would compile jax and MJX from source as it imports them. Its
# exit status is ignored: a package shipping a file for a newer Python (torch's py312 test
# helpers under 3.11) fails it, and bytecode is only a speed-up.
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -c constraints.txt -e '.[$(EXTRAS)]'
	$(BIN)/python -m compileall -q -j 0 $$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))') >/dev/null || true
	touch $(sort $(STAMP) $(VENV)/.installed)

demo: $(STAMP)
	$(BIN)/jaml demo --out runs/demo

# Two workers, one test file per worker at a time (module fixtures compile once): the suite is
# bound by single-threaded XLA compiles, so this halves the wall time on two cores.
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=15

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m slow

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[bench]'
	$(BIN)/python benchmarks/relations_fit.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
