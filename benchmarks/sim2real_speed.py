"""Speed of the sim-to-real diagnosis (target: a 20 s, 1 kHz arm log with the full catalogue in
<= 60 s on one core).

    .venv/bin/python -m benchmarks.sim2real_speed [--repeat 3]

Prints a table: per log, samples, channels, the wall and CPU seconds of `diagnose` (replay, every
arm effect fitted with blocked cross-validation and bootstrap intervals, forward selection, audit).
BLAS is held to one thread so that the numbers are one core's.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from sim2real.diagnosis import diagnose  # noqa: E402
from sim2real.importers import load_log  # noqa: E402
from sim2real.realistic import RealisticCase, make_case_log  # noqa: E402
from sim2real.reality import RealityConfig, make_arm_log  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    logs = {
        "real Panda (Gaz et al.), tau only": load_log(ROOT / "data" / "panda-gaz2019" / "log.npz"),
        "simulated 20 s, Panda logger, tau only (link_inertia at SNR 8)": make_case_log(
            RealisticCase("speed", ("link_inertia",), "single", 8.0, 0, "gaz"), 20.0
        )[0],
        "simulated 20 s, ideal sensors, tau + tau_cmd + control law": make_arm_log(
            {"coulomb": {"fc": 0.5}, "payload": {"dm": 0.5, "com_z": 0.05}}, RealityConfig(duration=20.0)
        ),
    }
    print("| log | samples | wall [s] (best of %d) | CPU [s] | verdict |" % args.repeat)
    print("|---|---|---|---|---|")
    for name, log in logs.items():
        walls, cpus = [], []
        for _ in range(args.repeat):
            w, c = time.perf_counter(), time.process_time()
            d = diagnose(log)
            walls.append(time.perf_counter() - w)
            cpus.append(time.process_time() - c)
        print(f"| {name} | {log.n_samples} | {min(walls):.1f} | {min(cpus):.1f} | {d.verdict['label']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
