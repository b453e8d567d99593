# goflow: `make demo` and `make test` need nothing but python3 (>= 3.10) on the machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test venv models clean

venv: $(STAMP)

# (Re)create .venv whenever pyproject.toml changes. torch goes first so that the CPU build is taken
# where one exists (a local +cpu wheel, then PyTorch's CPU index); plain PyPI torch is the fallback.
$(STAMP): pyproject.toml tools/setup_env.sh
	bash tools/setup_env.sh $(PYTHON) $(VENV)
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/goflow demo

# The test files run in parallel, one process per core (at most 4: each holds Drake and torch),
# each file whole on one worker, in the order tests/conftest.py sets (the long files first), and
# one math thread per worker (torch's and BLAS's default of one per core would oversubscribe).
test: $(STAMP)
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadfile --no-loadscope-reorder

# Regenerate every committed model file (bit-identical for the same code).
models: $(STAMP)
	$(BIN)/python -m assembly.generate_models

clean:
	rm -rf $(VENV) build *.egg-info
