# starnav: two commands on a fresh machine.
#   make demo   creates .venv, installs starnav, runs the main job on built-in defaults
#   make test   creates .venv with the dev extras, runs the test suite (slow tests excluded)
#               on one worker per core, at most 4 (pytest-xdist; a module's tests share a
#               worker, so its module-scoped renders are made once)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.starnav-installed

.PHONY: demo test test-slow bench bench-cycles lint llvm clean
CYCLES_VENV ?= .venv-cycles
# test workers: one per logical core, at most 4 (each worker holds its own renders and tables)
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

llvm:
	@bash tools/ensure-llvm.sh

demo: llvm $(STAMP)
	$(BIN)/starnav demo --out out/demo

test: llvm $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadscope

test-slow: llvm $(STAMP)
	$(BIN)/python -m pytest -m slow -n $(TEST_WORKERS) --dist loadscope

bench: llvm $(STAMP)
	for b in render detector navigation scenes dem calibration dataset; do \
	  echo "== benchmarks/$$b.py"; $(BIN)/python benchmarks/$$b.py || exit 1; done

# the render benchmark with Blender Cycles (the paper's engine) on the same frames: bpy pins
# numpy < 2 and Python 3.11, so it gets its own venv (a ~370 MB wheel from PyPI)
bench-cycles: llvm $(STAMP)
	test -x $(CYCLES_VENV)/bin/python || ($(PYTHON) -m venv $(CYCLES_VENV) && \
	  $(CYCLES_VENV)/bin/python -m pip install -q bpy)
	$(BIN)/python benchmarks/render.py --shapes real --cycles-python $(CYCLES_VENV)/bin/python

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks

clean:
	rm -rf $(VENV) $(CYCLES_VENV) out .pytest_cache
