# Two commands do all set-up on a fresh machine: `make run` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# Python writes the bytecode of what it imports, once: where PYTHONDONTWRITEBYTECODE is set, every
# process of a run would compile torch and the rest again on import.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: run test check-science docs lint bench results clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	# A CPU build of torch lies on disk here; an unpinned torch would pull a multi-GB CUDA build.
	# --no-compile: pip would compile all ~16,000 files of the environment one at a time; Python
	# compiles the modules a command imports on first use instead (see unexport above).
	$(BIN)/pip install -q --no-compile torch==2.13.0
	# Ray (the benchmark's cluster backend, 20 s of the install) only where a study needs it
	$(BIN)/pip install -q --no-compile -e '.[optimize,rl,dev,parquet,xlsx]'
	# Basilisk, the independent simulator of the diagnose harness, without pip resolving its pins
	# (they would downgrade matplotlib and others); where it cannot be
	# had, its tests skip.
	$(BIN)/pip install -q --no-compile --no-deps bsk==2.12.1 colorama==0.4.6 pooch==1.9.0 \
		|| echo "bsk not installed: the Basilisk tests will skip"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/inertia-gym optimize --agent bo --budget 100 --seed 0 --out runs/optimize

# --dist worksteal: each worker starts on its own share of the tests and takes over the rest of
# the other's when it runs out, so neither idles while a long module finishes on the other (a
# module's fixtures may then be built on both; the balance gains more than that costs).
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist worksteal --durations=15 -m "not science"

# The long studies (statistical sweeps, real-data tables): on demand, not in CI.
check-science: $(STAMP)
	$(BIN)/pip install -q --no-compile -e '.[ray]'
	$(BIN)/python -m pytest -q -n 2 --dist worksteal --durations=15 -m science

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check inertia_gym scripts tests docs

bench: $(STAMP)
	$(BIN)/python scripts/bench_speed.py

# Every study of docs/results.md rerun and its tables rewritten (over an hour on 2 cores;
# docs/results.py --list names the studies, --only KEY runs one).
results: $(STAMP)
	$(BIN)/python docs/results.py

clean:
	rm -rf $(VENV) runs .pytest_cache site
