"""What the tests share: loading a benchmark script (benchmarks/<name>.py) as a module, and the
order in which `make test` hands the test files to its workers."""

import subprocess
import importlib.util
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def benchmark_script() -> Callable[[str], ModuleType]:
    """A loader of benchmarks/<name>.py as the module <name> (registered in sys.modules, so its
    dataclasses and pickled functions resolve)."""

    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        return module

    return load


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Files with the most `slow` tests first, then files with the most tests (stable otherwise).

    `make test` gives whole files to its workers (`--dist loadfile --no-loadscope-reorder`), in
    this order: the long files start at once instead of running alone at the end of the run."""
    slow = Counter(item.path for item in items if item.get_closest_marker("slow"))
    count = Counter(item.path for item in items)
    items.sort(key=lambda item: (-slow[item.path], -count[item.path]))


@pytest.fixture
def run_goflow() -> Callable[..., subprocess.CompletedProcess]:
    """`goflow ARGS` run in this process through `goflow_cli.main`, as a subprocess would report
    it (exit status, stdout, stderr) but without starting Python and importing torch and Drake
    again; `cwd` runs it from that folder. Tests whose point is a process (Ctrl-C, the console
    script) start one instead."""
    import contextlib
    import io
    import subprocess

    from goflow_cli import main

    def run(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.ExitStack() as stack:
            if cwd is not None:
                stack.enter_context(contextlib.chdir(cwd))
            stack.enter_context(contextlib.redirect_stdout(out))
            stack.enter_context(contextlib.redirect_stderr(err))
            try:
                code = main([str(a) for a in args])
            except SystemExit as exc:  # argparse: --help, --version, a bad flag
                code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 2
        return subprocess.CompletedProcess(["goflow", *map(str, args)], code, out.getvalue(), err.getvalue())

    return run
