# goflow: `make demo` and `make test` need nothing but python3 (>= 3.10) on the machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test check venv models clean

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

# The inner loop (under 3 minutes): lint and format check, then the fast tests of the code every change touches
# (files, configs, layers, the CLI, the batched envs); `make test` runs everything.
check: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -x -m "not slow" -n auto --maxprocesses 4 --dist loadfile \
		tests/goflow_common tests/test_layers.py tests/test_benchmarks.py tests/test_cli.py \
		tests/assembly/test_params.py tests/assembly/test_samplers.py tests/assembly/test_batched.py \
		tests/learning/test_sampler_registry.py

# Regenerate every committed model file (bit-identical for the same code).
models: $(STAMP)
	$(BIN)/python -m assembly.generate_models

clean:
	rm -rf $(VENV) build *.egg-info
