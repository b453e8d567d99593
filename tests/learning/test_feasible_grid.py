"""A skill's feasible set measured on a grid, a flow against it, and the constrained refit."""

from __future__ import annotations

import numpy as np
import pytest

from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR
from goflow_common.errors import InputError
from learning.feasible_grid import (
    FeasibleGridConfig,
    FeasibleSet,
    FlowRefitConfig,
    constrained_copy,
    flow_report,
    refit_flow,
)
from learning.samplers.goflow import GoFlowSampler

SPACE = ParamSpace((Param("x", -1.0, 1.0, "m"), Param("y", -1.0, 1.0, "m")))


def disk(xi, centre=(0.1, -0.05), radius=0.15):
    return np.hypot(xi[:, 0] - centre[0], xi[:, 1] - centre[1]) <= radius


def measured(oracle=disk, fine_cells=40, coarse_cells=9, centre=(0.1, -0.05)):
    plan = FeasibleGridConfig(fine_width=0.5, fine_cells=fine_cells, coarse_cells=coarse_cells, centre=centre).plan(
        SPACE, np.zeros(2)
    )
    returns = np.where(oracle(plan.points()), 1.0, 0.0)
    return plan, plan.feasible_set(returns, 0.5, "fast")


def test_the_grid_runs_fine_cells_and_the_coarse_cells_outside_them():
    plan, fs = measured()
    np.testing.assert_allclose(plan.low, [-0.15, -0.3])
    np.testing.assert_allclose(plan.high, [0.35, 0.2])
    # 40 x 40 fine cells, and the 9 x 9 coarse cells but the four whose centres ((0, 0), (0.22, 0),
    # (0, -0.22), (0.22, -0.22)) lie in the fine region
    assert len(plan.points()) == 1600 + 77 and int(plan.coarse_run.sum()) == 77
    # a fine region that would leave the box is moved inside it
    edge = FeasibleGridConfig(fine_width=0.5, centre=(0.95, -1.0)).plan(SPACE, np.zeros(2))
    np.testing.assert_allclose(edge.low, [0.5, -1.0])


def test_the_measured_set_labels_every_point_of_the_box():
    _, fs = measured()
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (20000, 2))
    inside = disk(x)
    got = fs.contains(x)
    # inside the fine region, the cells resolve the disk to their size (0.0125)
    assert np.mean(got == inside) > 0.997
    # a success outside the fine region is found by the coarse cell it lies in
    two = lambda xi: disk(xi) | (np.hypot(xi[:, 0] + 0.67, xi[:, 1] - 0.67) < 0.05)
    _, fs2 = measured(two)
    assert fs2.coarse_success.sum() == 1 and fs2.contains(np.array([[-0.7, 0.7]]))[0]
    assert fs2.contains(np.array([[-0.67, 0.67], [-0.6, 0.6]])).all()  # the whole coarse cell counts
    assert not fs2.contains(np.array([[0.8, 0.8]]))[0]


def test_share_and_points_inside_are_uniform_on_the_set():
    _, fs = measured()
    inside, share = fs.sample_box(20000, np.random.default_rng(1))
    assert share == pytest.approx(np.pi * 0.15**2 / 4, rel=0.02)
    assert fs.contains(inside).all()
    # uniform on the disk: half of the points within radius 0.15 / sqrt(2) of its centre
    r = np.hypot(inside[:, 0] - 0.1, inside[:, 1] + 0.05)
    assert np.mean(r < 0.15 / np.sqrt(2)) == pytest.approx(0.5, abs=0.02)


def test_flow_report_of_the_uniform_box():
    _, fs = measured()
    report = flow_report(FullDR(SPACE), fs, samples=50_000)
    assert report["mass_on"] == pytest.approx(report["share"], abs=0.003)
    assert report["mass_on"] + report["mass_outside"] == pytest.approx(1.0)
    # the box's density is 1.8 % of the uniform-on-F density: above the 1 % level, below 10 %
    assert report["coverage10"] == 0.0 and report["coverage1"] == 1.0


def test_state_round_trip_and_a_foreign_state_is_refused():
    _, fs = measured()
    back = FeasibleSet.from_state_dict(fs.state_dict())
    x = np.random.default_rng(2).uniform(-1, 1, (1000, 2))
    np.testing.assert_array_equal(back.contains(x), fs.contains(x))
    with pytest.raises(ValueError, match="not a measured feasible set"):
        FeasibleSet.from_state_dict({"format": "something else"})


def test_bad_grid_and_refit_settings_name_the_value():
    with pytest.raises(InputError, match="fine_cells"):
        FeasibleGridConfig(fine_cells=(4, 4, 4)).plan(SPACE, np.zeros(2))
    with pytest.raises(InputError, match="fine_width"):
        FeasibleGridConfig(fine_width=-0.1).plan(SPACE, np.zeros(2))
    with pytest.raises(InputError, match="centre"):
        FeasibleGridConfig(centre=(0.0, np.nan)).plan(SPACE, np.zeros(2))
    for bad in (
        {"delta": 0.0},
        {"delta": 1.0},
        {"rounds": -1},
        {"episodes": 0},
        {"classifier_steps": 0},
        {"floor": 1.0},
        {"floor": -0.1},
    ):
        with pytest.raises(InputError, match=next(iter(bad))):
            FlowRefitConfig(**bad)


def test_the_refit_concentrates_on_and_covers_the_measured_set(tmp_path):
    """A broad flow refitted to a 2-D disk of 1.8 % of the box: the update from the grid and a few
    from its own draws put nearly all its mass on the set and cover it; a second call resumes
    from the checkpoint without new work."""
    _, fs = measured()
    flow = GoFlowSampler(SPACE, None, mode="paper", steps=60, proposal_samples=1024, fit_batch=256)
    calls = []

    def evaluate(xi, update):
        calls.append(update)
        return np.where(disk(xi), 1.0, 0.0)

    config = FlowRefitConfig(rounds=3, episodes=64, steps=60, classifier_steps=100)
    new, records = refit_flow(flow, fs, evaluate, config, checkpoint=tmp_path / "refit.pt")
    assert flow.config.mode == "paper" and new.config.mode == "constrained"
    assert new.config.floor == 0.0 and flow.config.floor == 0.2  # the refit's floor, not GoFlow's default
    assert [r["update"] for r in records] == [0, 1, 2, 3] and calls == [1, 2, 3]
    assert records[-1]["mass_on"] > 0.95 and records[-1]["coverage10"] > 0.9, records[-1]
    assert records[-1]["success_on_draws"] > 0.9
    again, same = refit_flow(flow, fs, evaluate, config, checkpoint=tmp_path / "refit.pt")
    assert calls == [1, 2, 3] and same == records
    x = np.random.default_rng(3).uniform(-1, 1, (100, 2))
    np.testing.assert_allclose(again.log_prob(x), new.log_prob(x))
    with pytest.raises(InputError, match="holds a refit"):
        refit_flow(
            flow,
            fs,
            evaluate,
            FlowRefitConfig(rounds=4, steps=60, classifier_steps=100),
            checkpoint=tmp_path / "refit.pt",
        )


def test_the_refit_keeps_a_classifier_of_its_own_layers_only():
    """A refit's copy continues from the source's classifier when the layers agree and fits its
    own when they do not (a 6-D flow saved before the width followed the dimension)."""
    space = ParamSpace(tuple(Param(f"p{i}", 0.0, 1.0, "1") for i in range(6)))
    kw = dict(mode="constrained", steps=2, proposal_samples=128, fit_batch=64, classifier_steps=3)
    rng = np.random.default_rng(0)
    xi = rng.uniform(size=(128, 6))
    u = rng.uniform(size=(50, 6))
    for layers, kept in (((128, 128), True), ((64, 64), False)):
        source = GoFlowSampler(space, None, classifier_hidden=layers, **kw)
        source.update(xi, (np.linalg.norm(xi - 0.5, axis=1) < 0.5).astype(float))
        copy = constrained_copy(source, FlowRefitConfig(steps=2, classifier_steps=3))
        assert copy._classifier.hidden == (128, 128)
        assert copy._classifier.fitted == kept
        if kept:
            np.testing.assert_array_equal(copy._classifier.probability(u), source._classifier.probability(u))


def test_frozen_refit_benchmark_runs_on_a_toy2d_run(tmp_path):
    """benchmarks/frozen_refit.py on a tiny GoFlow run: the policy's set measured on a grid, the
    flow refitted, both reported against Toy2D's own feasible set."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from learning.experiment import TrainConfig, train
    from learning.ppo import PPOConfig

    run = tmp_path / "run"
    train(
        TrainConfig(
            env="goflow/Toy2D-v0",
            method="goflow",
            seed=1,
            eval_episodes=16,
            iterations_per_round=1,
            total_steps=2 * 4 * 16,
            out=run,
            sampler_kwargs={"steps": 3, "report_samples": 256},
            ppo=PPOConfig(num_envs=4, num_steps=16, num_minibatches=2, update_epochs=1),
        ),
        progress=False,
    )
    script = Path(__file__).parents[2] / "benchmarks" / "frozen_refit.py"
    out = tmp_path / "refit.json"
    proc = subprocess.run(
        [
            sys.executable,
            str(script),
            "--runs",
            str(run),
            "--cells",
            "10",
            "--repeats",
            "2",
            "--rounds",
            "1",
            "--episodes",
            "16",
            "--steps",
            "5",
            "--classifier-steps",
            "5",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    row = json.loads(out.read_text())["rows"][0]
    assert [u["episodes"] for u in row["updates"]] == [100, 16]
    for key in ("policy_set", "env_set"):
        assert set(row[key]["after"]) >= {"share", "mass_on", "coverage10", "coverage1"}
    assert 0.05 < row["env_set"]["after"]["share"] < 0.15  # the circle layout's 9 %
    bad = subprocess.run(
        [sys.executable, str(script), "--runs", str(run), "--level", "1.5"], capture_output=True, text=True, timeout=120
    )
    assert bad.returncode != 0 and "--level must lie in (0, 1], got 1.5" in bad.stderr


@pytest.mark.slow
def test_skill_feasible_mc_benchmark_measures_a_shipped_flow_and_resumes(tmp_path):
    """benchmarks/skill_feasible_mc.py at a tiny size on the shipped small gear: the episodes'
    mass and coverage beside the grid's, every part saved, and a second call runs no episode."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).parents[2] / "benchmarks" / "skill_feasible_mc.py"
    args = [
        sys.executable,
        str(script),
        "--gear",
        "small",
        "--draws",
        "2",
        "--uniform",
        "3",
        "--part",
        "2",
        "--out",
        str(tmp_path / "parts"),
    ]
    first = subprocess.run([*args, "--json", str(tmp_path / "row.json")], capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    row = json.loads((tmp_path / "row.json").read_text())
    assert row["variants"] == "fast+panda" and row["draws"] == 2 and row["uniform"] == 3
    assert 0.0 <= row["episodes"]["mass_on"] <= 1.0 and row["grid"]["share"] == pytest.approx(0.0038, abs=0.0005)
    assert "skill_feasible_mc: small draws2 fast rows 0-2 of 2" in first.stdout
    again = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and " rows " not in again.stdout  # every part read back, no episode run
    for bad, named in ((["--gear", "tiny"], "--gear 'tiny'"), (["--gear", "small", "--uniform", "0"], "--uniform = 0")):
        proc = subprocess.run([sys.executable, str(script), *bad], capture_output=True, text=True, timeout=120)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and named in lines[0]
