"""The lasting benchmarks and calibration scripts (benchmarks/README.md): run each from the
repository root as `.venv/bin/python -m benchmarks.<name>`."""
