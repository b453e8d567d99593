"""Known feasible sets and the measures against them (learning/feasible_sets.py), and the sampler
quality benchmark built on them (benchmarks/sampler_quality.py)."""

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from assembly.samplers import FullDR
from goflow_common.errors import InputError
from learning.feasible_sets import (
    LAYOUTS,
    MC_SEED,
    coverage,
    kl_to_optimum,
    mass_on,
    optimum_log_prob,
    optimum_mass,
    unit_space,
)

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "sampler_quality.py"
DELTA = 0.005


def _benchmark(script: Path = SCRIPT):
    """A benchmarks/ script as a module (default sampler_quality.py)."""
    spec = importlib.util.spec_from_file_location(script.stem, script)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _uniform_on(layout):
    """log_prob of the distribution uniform on the layout's feasible set F."""
    return lambda x: np.where(layout.contains(x), -math.log(layout.share), -math.inf)


# -- the layouts ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_share_matches_an_independent_monte_carlo(name):
    layout = LAYOUTS[name]
    n = 400_000 if layout.dim < 6 else 100_000
    mc = layout.monte_carlo_share(n, seed=MC_SEED + 1)
    se = math.sqrt(layout.share * (1 - layout.share) / n)
    # an analytic share against one Monte Carlo; a Monte Carlo share against another (both random)
    tolerance = 5 * se * (1.0 if layout.exact_share is not None else math.sqrt(2.0))
    assert abs(mc - layout.share) < tolerance, (name, mc, layout.share)


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_reward_contains_and_sample_inside_agree(name):
    layout = LAYOUTS[name]
    rng = np.random.default_rng(0)
    x = rng.random((20_000, layout.dim))
    r, inside = layout.reward(x), layout.contains(x)
    assert r.shape == inside.shape == (20_000,) and np.all((r >= 0) & (r <= 1))
    np.testing.assert_array_equal(inside, r >= 0.5)
    if not layout.graded:
        np.testing.assert_array_equal(inside, r == 1.0)
    else:  # a plateau at 1, zero far away, a ramp between
        assert (r == 1.0).any() and (r == 0.0).any() and ((r > 0) & (r < 1)).any()
    pts = layout.sample_inside(500, rng)
    assert pts.shape == (500, layout.dim) and layout.contains(pts).all()
    assert layout.space.dim == layout.dim and layout.volume == 1.0


def test_the_suite_is_varied():
    dims = sorted({layout.dim for layout in LAYOUTS.values()})
    assert dims == [1, 2, 3, 6]
    shares = {name: layout.share for name, layout in LAYOUTS.items()}
    assert shares["tiny"] < 0.01 and abs(shares["small"] - 0.05) < 1e-12 and abs(shares["halfplane"] - 0.48) < 1e-12
    assert 0.05 <= shares["ellipsoid6d"] <= 0.2
    assert {name for name, layout in LAYOUTS.items() if layout.graded} == {"graded1d", "graded2d"}


# -- the measures ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["disks", "small", "ellipsoid3d"])
def test_uniform_sampler_mass_is_the_share_and_it_covers_at_levels_below_the_share(name):
    layout = LAYOUTS[name]
    sampler = FullDR(layout.space)
    n = 20_000
    mass = mass_on(sampler.sample(n, np.random.default_rng(1)), layout.contains)
    assert abs(mass - layout.share) < 5 * math.sqrt(layout.share * (1 - layout.share) / n)
    inside = layout.sample_inside(2000, np.random.default_rng(2))
    # the uniform box's density 1 exceeds level / share exactly when level < share
    for level in (0.1, 0.01):
        expected = 1.0 if level < layout.share else 0.0
        assert coverage(sampler.log_prob, inside, layout.share, level) == expected


@pytest.mark.parametrize("name", ["disks", "strip", "graded2d", "ellipsoid6d"])
def test_a_sampler_uniform_on_the_feasible_set_is_the_constrained_optimum_up_to_delta(name):
    layout = LAYOUTS[name]
    draws = layout.sample_inside(4000, np.random.default_rng(3))
    log_prob = _uniform_on(layout)
    assert mass_on(draws, layout.contains) == 1.0
    inside = layout.sample_inside(2000, np.random.default_rng(4))
    assert coverage(log_prob, inside, layout.share, 0.1) == 1.0
    assert coverage(log_prob, inside, layout.share, 0.01) == 1.0
    kl = kl_to_optimum(draws, log_prob, layout, ("constrained", DELTA))
    assert kl == pytest.approx(math.log(1.0 / (1.0 - DELTA)), abs=1e-9)


def test_half_of_the_feasible_set_is_half_covered():
    layout = LAYOUTS["halfplane"]
    # twice the uniform-on-F density where p1 < 0.5, zero elsewhere: covers the part of F below 0.5
    lower = LAYOUTS["halfplane"].sample_inside(20_000, np.random.default_rng(5))
    lower_share = float(np.mean(lower[:, 1] < 0.5))  # F's fraction below p1 = 0.5
    log_prob = lambda x: np.where(
        layout.contains(x) & (x[:, 1] < 0.5),  # noqa: E731
        -math.log(layout.share * lower_share),
        -math.inf,
    )
    assert coverage(log_prob, lower, layout.share, 0.1) == pytest.approx(lower_share)


def test_kl_to_the_entropy_optimum_of_the_uniform_box_is_log_z_minus_the_mean_reward():
    layout = LAYOUTS["ring"]
    s, alpha = layout.share, 0.3
    log_z = math.log(s * math.exp(1 / alpha) + 1 - s)
    draws = np.random.default_rng(6).random((200_000, 2))
    kl = kl_to_optimum(draws, lambda x: np.zeros(len(x)), layout, ("entropy", alpha))
    se = (1 / alpha) * math.sqrt(s * (1 - s) / len(draws))
    assert kl == pytest.approx(log_z - s / alpha, abs=5 * se)
    # p* puts e^{1/a} s / Z of its mass on F
    assert optimum_mass(layout, ("entropy", alpha)) == pytest.approx(s * math.exp(1 / alpha) / math.exp(log_z))
    assert optimum_mass(layout, ("constrained", DELTA)) == 1 - DELTA


@pytest.mark.parametrize("name", ["graded1d", "graded2d"])
@pytest.mark.parametrize("alpha", [0.1, 1.0])
def test_graded_optimum_is_normalized(name, alpha):
    layout = LAYOUTS[name]
    x = np.random.default_rng(7).random((400_000, layout.dim))  # not the points behind log Z
    p = np.exp(optimum_log_prob(layout, ("entropy", alpha))(x))
    assert np.mean(p) == pytest.approx(1.0, abs=5 * np.std(p) / math.sqrt(len(x)))
    # the optimum's own draws (by rejection from the box) have KL 0 to it
    log_p = optimum_log_prob(layout, ("entropy", alpha))
    keep = np.random.default_rng(8).random(len(x)) < p / p.max()
    assert kl_to_optimum(x[keep], log_p, layout, ("entropy", alpha)) == pytest.approx(0.0, abs=1e-12)


def test_measures_refuse_bad_input():
    layout = LAYOUTS["disks"]
    inside = layout.sample_inside(10, np.random.default_rng(0))
    flat = lambda x: np.zeros(len(x))  # noqa: E731
    with pytest.raises(InputError, match="share"):
        coverage(flat, inside, 0.0, 0.1)
    with pytest.raises(InputError, match="level"):
        coverage(flat, inside, 0.2, -1.0)
    with pytest.raises(InputError, match="objective kind"):
        kl_to_optimum(inside, flat, layout, ("entropic", 1.0))
    with pytest.raises(InputError, match="delta"):
        kl_to_optimum(inside, flat, layout, ("constrained", 1.5))
    with pytest.raises(InputError, match="shape"):
        layout.reward(np.zeros((3, 3)))
    with pytest.raises(InputError, match="finite"):
        mass_on(np.full((2, 2), np.nan), layout.contains)
    with pytest.raises(InputError, match="NaN"):
        coverage(lambda x: np.full(len(x), np.nan), inside, 0.2, 0.1)
    assert unit_space(3).names == ("p0", "p1", "p2")


# -- the benchmark ----------------------------------------------------------------------------------


def _script(*args, cwd=ROOT):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize(
    "args, named",
    [
        (["--layouts", "moon"], "'moon'"),
        (["--methods", "goflow-fancy"], "'goflow-fancy'"),
        (["--protocols", "mine"], "'mine'"),
        (["--rounds", "0"], "--rounds = 0"),
        (["--rounds", "ten"], "'ten'"),
        (["--seeds", "a,b"], "--seeds"),
        (["--batch", "1"], "--batch = 1"),
        (["--checkpoint-every", "-5"], "--checkpoint-every = -5"),
        (["--methods", "adr", "--protocols", "uniform"], "ADR runs only under --protocols own"),
        (["--methods", "goflow-constrained", "--sampler", "leak_targt=0.01"], "'leak_targt'"),
        (["--methods", "goflow-constrained", "--sampler", "leak_target=-1"], "--sampler leak_target=-1"),
        (["--methods", "goflow-constrained", "--sampler", "seed=3"], "--sampler seed="),
        (["--methods", "goflow-constrained", "lsdr", "--sampler", "leak_target=0.01"], "['lsdr']"),
    ],
)
def test_benchmark_bad_input_is_one_line(args, named, tmp_path):
    proc = _script(*args, "--out", str(tmp_path / "out"))
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0] and lines[0].startswith("sampler_quality: "), proc.stderr


def test_benchmark_tiny_run_writes_json_and_resumes(tmp_path):
    out = tmp_path / "out"
    args = [
        "--layouts",
        "small",
        "--methods",
        "uniform",
        "lsdr",
        "--protocols",
        "uniform",
        "--seeds",
        "1",
        "--rounds",
        "2",
        "--batch",
        "32",
        "--draws",
        "256",
        "--out",
        str(out),
    ]
    first = _script(*args)
    assert first.returncode == 0, first.stderr
    runs = sorted(p.relative_to(out).as_posix() for p in out.rglob("seed*.json"))
    assert runs == ["small/lsdr/uniform/seed0.json", "small/uniform/uniform/seed0.json"]
    summary = json.loads((out / "summary.json").read_text())
    assert {r["method"] for r in summary["rows"]} == {"uniform", "lsdr"}
    assert summary["rows"][0]["rounds"] == [0, 2]
    record = json.loads((out / "small/lsdr/uniform/seed0.json").read_text())
    assert len(record["update_s"]) == 2 and len(record["density"]["log_prob"]) == 64
    second = _script(*args)
    assert second.returncode == 0, second.stderr
    assert "2 already in" in second.stdout and "0 to run" in second.stdout
    # the same folder with other settings is refused, not silently mixed
    third = _script(*args[:-4], "--rounds", "3", "--out", str(out))
    assert third.returncode == 2 and "other settings" in third.stderr


@pytest.mark.parametrize(
    "method, protocol", [("lsdr", "own"), ("doraemon", "uniform"), ("adr", "own"), ("goflow-constrained", "own")]
)
def test_benchmark_same_seed_same_row(method, protocol):
    bench = _benchmark()
    task = bench.Task("small", method, protocol, seed=3, rounds=2, batch=32, draws=256)
    a, b = bench.run_task(task), bench.run_task(task)
    strip = lambda rec: [{k: v for k, v in row.items() if k != "update_s"} for row in rec["rows"]]  # noqa: E731
    assert strip(a) == strip(b)
    assert a["density"] == b["density"]
    if method == "lsdr":  # and another seed another row
        other = bench.run_task(bench.Task("small", method, protocol, seed=4, rounds=2, batch=32, draws=256))
        assert strip(other) != strip(a)


@pytest.mark.parametrize("method, protocol", [("goflow-constrained", "own"), ("doraemon", "uniform")])
def test_benchmark_run_interrupted_resumes_from_its_checkpoint_to_the_same_rows(
    method, protocol, tmp_path, monkeypatch
):
    from learning.samplers.registry import make_sampler

    bench = _benchmark()
    # fewer gradient steps than the defaults for GoFlow: what is checked is the resume, not the fit
    fewer = (("classifier_steps", 10), ("steps", 10)) if bench.METHODS[method].sampler == "goflow" else ()
    task = bench.Task("small", method, protocol, seed=1, rounds=6, batch=32, draws=256, overrides=fewer)
    straight = bench.run_task(task)
    cls = type(make_sampler(bench.METHODS[method].sampler, bench.LAYOUTS["small"].space, bench.J_T, {}))
    update, calls = cls.update, []

    def interrupted(self, *args, **kwargs):  # Ctrl-C during the 5th update
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return update(self, *args, **kwargs)

    monkeypatch.setattr(cls, "update", interrupted)
    with pytest.raises(KeyboardInterrupt):
        bench.run_and_save(task, tmp_path, checkpoint_every=3)
    monkeypatch.setattr(cls, "update", update)
    checkpoint = bench.partial_path(task, tmp_path)
    assert json.loads(checkpoint.read_text())["round"] == 3 and not task.path(tmp_path).exists()
    resumed = bench.run_and_save(task, tmp_path, checkpoint_every=3)
    strip = lambda rec: [{k: v for k, v in row.items() if k != "update_s"} for row in rec["rows"]]  # noqa: E731
    assert strip(resumed) == strip(straight) and resumed["density"] == straight["density"]
    assert len(resumed["update_s"]) == 6 and not checkpoint.exists() and task.path(tmp_path).exists()
    # a stored run without a config field added since (at its default) is still this run
    stored = json.loads(task.path(tmp_path).read_text())
    defaults = bench.default_config(task)
    added = next(k for k, v in stored["config"].items() if k != "seed" and v == defaults[k])
    del stored["config"][added]
    task.path(tmp_path).write_text(json.dumps(stored))
    assert bench.stored(task, tmp_path)["rows"] == resumed["rows"]
    # a checkpoint of other settings is refused, naming the difference
    other = bench.Task("small", method, protocol, seed=1, rounds=7, batch=32, draws=256, overrides=fewer)
    bench.partial_path(other, tmp_path).write_text(checkpoint.parent.joinpath("seed1.json").read_text())
    with pytest.raises(InputError, match="rounds 6 \\(want 7\\)"):
        bench.run_task(other, tmp_path, checkpoint_every=3)


def test_benchmark_sampler_flag_reaches_the_goflow_config_and_the_stored_settings():
    from learning.samplers.registry import make_sampler

    bench = _benchmark()
    args = bench.make_parser().parse_args(
        [
            "--layouts",
            "small",
            "--methods",
            "goflow-constrained",
            "--protocols",
            "uniform",
            "--seeds",
            "2,",
            "--sampler",
            "leak_target=0.008",
            "--sampler",
            "hidden_features=[32, 32]",
        ]
    )
    (task,) = bench.plan(args)
    assert task.overrides == (("hidden_features", (32, 32)), ("leak_target", 0.008))
    method = bench.METHODS[task.method]
    config = bench.sampler_config(method, task.protocol, task.seed, task.overrides)
    sampler = make_sampler(method.sampler, bench.LAYOUTS["small"].space, bench.J_T, config)
    assert sampler.config.leak_target == 0.008 and sampler.config.hidden_features == (32, 32)
    assert sampler.config.mode == "constrained" and sampler.config.seed == 2  # the method's own options stay
    # a run with other overrides has other settings: never reused as "already present"
    plain = bench.Task(
        *[getattr(task, f) for f in ("layout", "method", "protocol", "seed", "rounds", "batch", "draws")]
    )
    assert task.settings()["config"]["leak_target"] == 0.008 and plain.settings()["config"]["leak_target"] == 0.004
    assert task.settings() != plain.settings()


# -- the classifier frontier (benchmarks/classifier_frontier.py) ------------------------------------


FRONTIER = ROOT / "benchmarks" / "classifier_frontier.py"


def test_frontier_reads_an_exact_estimate_as_meeting_both_targets_and_a_loose_one_as_not():
    frontier, layout = _benchmark(FRONTIER), LAYOUTS["small"]
    rng = np.random.default_rng(0)
    u, inside = rng.random((200_000, 2)), layout.sample_inside(20_000, rng)
    in_f = layout.contains(u)
    exact = frontier.read_levels(in_f.astype(float), in_f, np.ones(len(inside)), [0.5], layout.share, 0.002)[0]
    assert exact["mass"] == pytest.approx(0.998) and exact["cov10"] == 1.0 and exact["recall"] == 1.0
    assert frontier.meets(exact)
    # F-hat twice F's area around it: every point of F covered, half the mass outside
    margin = layout.margin(u)
    loose_p = (margin >= np.quantile(margin, 1.0 - 2.0 * layout.share)).astype(float)
    loose = frontier.read_levels(loose_p, in_f, np.ones(len(inside)), [0.5], layout.share, 0.002)[0]
    assert loose["cov10"] == 1.0 and loose["mass"] == pytest.approx(0.5, abs=0.02) and not frontier.meets(loose)
    # an empty F-hat: the flow alone, uniform on the box, covers none of a 5 % set at the 10 % level
    empty = frontier.read_levels(np.zeros(len(u)), in_f, np.zeros(len(inside)), [0.5], layout.share, 0.002)[0]
    assert empty["mass"] == pytest.approx(layout.share) and empty["cov10"] == 0.0


def test_frontier_weights_read_a_stratified_sample_as_the_uniform_one():
    frontier, layout = _benchmark(FRONTIER), LAYOUTS["small"]
    rng = np.random.default_rng(1)
    u, inside = rng.random((400_000, 2)), layout.sample_inside(20_000, rng)
    p_hat = layout.contains(u).astype(float) * 0.9 + 0.05 * (layout.margin(u) > -0.02)
    plain = frontier.read_levels(p_hat, layout.contains(u), np.ones(len(inside)), [0.5, 0.9], layout.share, 0.002)
    # a quarter of the points in the left half of the box, weighted back to uniform
    more = rng.random((800_000, 2))
    left = more[:, 0] < 0.5
    strat = np.concatenate([more[left][:100_000], more[~left][:300_000]])
    weights = np.where(strat[:, 0] < 0.5, 0.5 / 0.25, 0.5 / 0.75)
    p_strat = layout.contains(strat).astype(float) * 0.9 + 0.05 * (layout.margin(strat) > -0.02)
    weighted = frontier.read_levels(
        p_strat, layout.contains(strat), np.ones(len(inside)), [0.5, 0.9], layout.share, 0.002, weights
    )
    for a, b in zip(plain, weighted):
        assert a["share"] == pytest.approx(b["share"], rel=0.05) and a["mass"] == pytest.approx(b["mass"], abs=0.01)


def test_frontier_grid_rows_carry_their_cells_labels():
    frontier = _benchmark(FRONTIER)
    from learning.skill_file import load_skill

    feasible = load_skill("insert", gear="small").feasible
    xi, success = frontier.grid_rows(feasible, 2, 0)
    n = len(feasible.points(np.random.default_rng([0, 0]))[0])
    assert xi.shape == (2 * n, 3) and np.all((xi >= 0) & (xi <= 1))
    space = feasible.space
    assert np.array_equal(success.astype(bool), feasible.contains(space.low + (space.high - space.low) * xi))
    assert int(success.sum()) > 0


@pytest.mark.parametrize(
    "args, named",
    [
        (["--levels", "1.5"], "--levels entry = 1.5"),
        (["--boundary-memory", "-1"], "--boundary-memory entry = -1"),
        (["--skills", "tiny"], "--skills: 'tiny'"),
        (["--skills", "small", "--per-cell", "0"], "--per-cell entry = 0"),
    ],
)
def test_frontier_bad_input_is_one_line(args, named):
    proc = subprocess.run([sys.executable, str(FRONTIER), *args], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0] and lines[0].startswith("classifier_frontier: ")
