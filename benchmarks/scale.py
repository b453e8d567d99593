"""How a grid of short training runs scales: the same grid on the local process pool, on a local Ray
with 1 worker and with 2 workers, in one run; the scaling ratio and Ray's overhead per task.

The grid: Toy2D runs (methods x seeds, `--steps` each), every run a job of learning.execution. For
each backend: the wall time of the grid, the sum of the runs' own times (measured inside the
worker), and the overhead per task = (workers x wall - sum of run times) / runs, which holds what
the backend adds to a run (scheduling, transfers, a worker's start and imports) plus, with 2
workers, the time a worker waits at the end of the grid. Ray's grid is run twice: "cold" on fresh
workers (each imports torch, Drake and the envs once), "warm" on the same workers again (the regime
of a long grid, where a worker runs many tasks). The runs' results are checked to be identical on
every backend. Last, `--noop` empty tasks on one worker give the backend's own cost per task,
without a training run's variation.

Usage: .venv/bin/python -m benchmarks.scale --seeds 2 --steps 3072 --json runs/scale.json
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


from goflow_common.files import check_output_file, write_json
from learning.execution import Backend, Job, PoolBackend, RayBackend, run_jobs
from learning.experiment import ExperimentConfig, experiment_jobs
from learning.ppo import PPOConfig

# Toy2D learns something within a few thousand steps with these (docs/learning.md's Toy2D options).
PPO = PPOConfig(num_envs=4, num_steps=64, num_minibatches=2, update_epochs=2, learning_rate=0.003, init_log_std=-1.0)


def grid(out: Path, seeds: int, steps: int) -> ExperimentConfig:
    return ExperimentConfig(
        env="goflow/Toy2D-v0",
        methods=("fulldr", "lsdr"),
        seeds=seeds,
        total_steps=steps,
        iterations_per_round=2,
        eval_episodes=64,
        ppo=PPO,
        out=out,
    )


def measure(label: str, backend: Backend, workers: int, config: ExperimentConfig) -> dict:
    """Run the grid on `backend` (entered already): wall time, run times, overhead per task."""
    jobs = experiment_jobs(config)
    t0 = time.perf_counter()
    outcomes = run_jobs(jobs, backend, progress=False)
    wall = time.perf_counter() - t0
    bad = [o for o in outcomes if o.status != "done"]
    if bad:
        raise SystemExit(f"scale: {label}: {bad[0].name} {bad[0].status}: {bad[0].error}")
    task = [o.seconds for o in outcomes]
    overhead = (workers * wall - sum(task)) / len(task)
    mean_task = sum(task) / len(task)
    return {
        "backend": label,
        "workers": workers,
        "runs": len(task),
        "wall_s": wall,
        "task_sum_s": sum(task),
        "task_mean_s": mean_task,
        "overhead_per_task_s": overhead,
        "overhead_share": overhead / mean_task,
        "curves": [o.value["curve"] for o in outcomes],
    }


def measure_noop(label: str, backend: Backend, tasks: int) -> dict:
    """`tasks` empty jobs on one worker: the wall time per task is the backend's own cost."""
    jobs = [Job(f"noop {i}", time.sleep, (0.0,)) for i in range(tasks)]
    run_jobs(jobs[:1], backend, progress=False)  # the worker started once, outside the timing
    t0 = time.perf_counter()
    run_jobs(jobs, backend, progress=False)
    wall = time.perf_counter() - t0
    return {"backend": label, "workers": 1, "runs": tasks, "wall_s": wall, "overhead_per_task_s": wall / tasks}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, default=2, help="seeds per method (2 methods)")
    p.add_argument("--steps", type=int, default=3072, help="training steps per run (rounds of 512)")
    p.add_argument("--noop", type=int, default=50, help="empty tasks timed on one worker")
    p.add_argument("--json", type=Path, help="write the table as JSON")
    args = p.parse_args()
    if args.json:
        check_output_file(args.json, "--json")
    rows, noops, load_start = [], [], os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="goflow-scale-") as tmp:
        folder = iter(range(100))

        def fresh() -> ExperimentConfig:  # a new run folder for every grid: nothing resumes
            return grid(Path(tmp) / f"g{next(folder)}", args.seeds, args.steps)

        rows.append(measure("pool", PoolBackend(2), 2, fresh()))
        for workers in (1, 2):
            t0 = time.perf_counter()
            with RayBackend("local", workers=workers) as ray:
                start = time.perf_counter() - t0
                cold = measure("ray cold", ray, workers, fresh())
                warm = measure("ray warm", ray, workers, fresh())
                if workers == 1:
                    noops.append(measure_noop("Ray, empty tasks", ray, args.noop))
            cold["start_s"] = warm["start_s"] = start
            rows += [cold, warm]
    same = all(r["curves"] == rows[0]["curves"] for r in rows)
    by = {(r["backend"], r["workers"]): r for r in rows}
    scaling = by[("ray warm", 1)]["wall_s"] / by[("ray warm", 2)]["wall_s"]
    load = os.getloadavg()
    print(
        f"grid: Toy2D, {rows[0]['runs']} runs of {args.steps} steps; {os.cpu_count()} CPUs, 1-minute load average "
        f"{load_start[0]:.2f} at the start, {load[0]:.2f} at the end"
    )
    print(
        "| backend | workers | Ray start [s] | grid wall [s] | sum of runs [s] | mean run [s] | overhead per task [s] "
        "| overhead / mean run |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        start = f"{r['start_s']:.1f}" if "start_s" in r else "-"
        print(
            f"| {r['backend']} | {r['workers']} | {start} | {r['wall_s']:.1f} | {r['task_sum_s']:.1f} | "
            f"{r['task_mean_s']:.2f} | {r['overhead_per_task_s']:.2f} | {100 * r['overhead_share']:.1f} % |"
        )
    for r in noops:
        print(
            f"{r['backend']}: {r['runs']} on 1 worker in {r['wall_s']:.2f} s, {1000 * r['overhead_per_task_s']:.1f} ms "
            "per task"
        )
    print(f"scaling, Ray warm, 1 -> 2 workers: {scaling:.2f}x (ideal 2.00 on 2 idle cores)")
    print(f"results identical on every backend: {'yes' if same else 'NO'}")
    if args.json:
        write_json(
            args.json,
            {
                "command": "python -m benchmarks.scale " + " ".join(sys.argv[1:]),
                "steps": args.steps,
                "cpus": os.cpu_count(),
                "load_average_1min": [load_start[0], load[0]],
                "scaling_warm_1_to_2": scaling,
                "identical": same,
                "rows": [{k: v for k, v in r.items() if k != "curves"} for r in rows],
                "empty_tasks": noops,
            },
        )
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
