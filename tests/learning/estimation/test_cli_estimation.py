"""`goflow collect` and `goflow estimate` as a user runs them."""

import json

import numpy as np
import pytest


def test_collect_then_estimate_gives_a_sampler_file(tmp_path, run_goflow):
    data = tmp_path / "pm.npz"
    proc = run_goflow(
        "collect",
        "--env",
        "goflow/PointMass-v0",
        "--true-xi",
        "mixture",
        "--episodes",
        "6",
        "--steps",
        "8",
        "--seed",
        "1",
        "--out",
        str(data),
    )
    assert proc.returncode == 0, proc.stderr
    from learning.estimation.dataset import load_dataset

    ds = load_dataset(data)
    assert ds.num_episodes == 6 and ds.collection["command"].startswith("goflow collect")
    out = tmp_path / "est.json"
    proc = run_goflow(
        "estimate",
        "--data",
        str(data),
        "--method",
        "dropo",
        "--sim-budget",
        "3000",
        "--method-kwarg",
        "samples=10",
        "--method-kwarg",
        "transitions=8",
        "--out",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    from learning.estimation.estimate_file import load_estimate

    sampler, doc = load_estimate(out)
    assert doc["method"] == "dropo" and doc["info"]["sim_calls"] <= 3000
    assert np.all(ds.space.contains(sampler.sample(10, np.random.default_rng(0))))
    assert json.loads(out.read_text())["env_id"] == "goflow/PointMass-v0"


def test_bad_flags_are_explained(tmp_path, run_goflow):
    proc = run_goflow(
        "collect",
        "--env",
        "goflow/Nope-v0",
        "--true-xi",
        "gaussian",
        "--episodes",
        "2",
        "--out",
        str(tmp_path / "x.npz"),
    )
    assert proc.returncode != 0 and "no step-from-state simulator for env 'goflow/Nope-v0'" in proc.stderr
    proc = run_goflow(
        "collect",
        "--env",
        "goflow/PointMass-v0",
        "--true-xi",
        "uniform",
        "--episodes",
        "2",
        "--out",
        str(tmp_path / "x.npz"),
    )
    assert proc.returncode == 2 and "invalid choice: 'uniform'" in proc.stderr
    proc = run_goflow(
        "estimate",
        "--data",
        str(tmp_path / "missing.npz"),
        "--method",
        "nfpde-softmax",
        "--out",
        str(tmp_path / "e.json"),
    )
    assert proc.returncode != 0 and "no such file" in proc.stderr
    proc = run_goflow("estimate", "--data", str(tmp_path / "m.npz"), "--method", "mle", "--out", "e.json")
    assert proc.returncode == 2 and "invalid choice: 'mle'" in proc.stderr


# Budgets (issue 15, defect 6): a budget below one iteration used to make 0 simulator calls and
# write the untouched prior with exit code 0 (DROPO's with `Infinity` in it).

METHOD_OPTION = "--method-kwarg"  # `goflow estimate`'s KEY=VALUE flag for the method's config


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    from learning.estimation.collect import CollectConfig, collect_to_file

    path = tmp_path_factory.mktemp("data") / "pm.npz"
    ds = collect_to_file(CollectConfig(env="goflow/PointMass-v0", xi="mixture", episodes=6, steps=20, seed=1), path)
    return path, ds


def test_budget_below_one_iteration_is_refused_by_the_cli(tmp_path, small_data, run_goflow):
    data, _ = small_data
    out = tmp_path / "est.json"
    # DROPO's defaults on 2 parameters: 8 candidates x 32 draws x 16 transitions per generation
    proc = run_goflow("estimate", "--data", str(data), "--method", "dropo", "--sim-budget", "3000", "--out", str(out))
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert (
        "sim_budget = 3000; dropo needs at least 4096 simulator calls for one iteration on this dataset "
        "(one CMA-ES generation: 8 candidates x 32 samples x 16 transitions"
    ) in lines[0]
    assert not out.exists()


@pytest.mark.parametrize("method", ["nfpde-softmax", "nfpde-cai", "dropo", "bayessim"])
def test_every_method_refuses_a_budget_below_its_minimum_before_simulating(small_data, method):
    from goflow_common.errors import InputError
    from learning.estimation.estimate import EstimateConfig, estimate, min_sim_calls

    _, ds = small_data
    need, _ = min_sim_calls(EstimateConfig(method=method), ds)
    assert (
        need
        == {"nfpde-softmax": 64 * 16 * 2, "nfpde-cai": 64 * 16 * 2, "dropo": 8 * 32 * 16, "bayessim": 2 * 16}[method]
    )
    with pytest.raises(InputError, match=f"sim_budget = {need - 1}; {method} needs at least {need} simulator calls"):
        estimate(ds, EstimateConfig(method=method, sim_budget=need - 1), sim=object())  # the sim is never touched


def test_one_iteration_budget_gives_strict_json_and_a_progress_bar(tmp_path, small_data, run_goflow):
    data, _ = small_data
    out = tmp_path / "est.json"
    # 8 candidates x 10 draws x 8 transitions = 640 calls: exactly one CMA-ES generation
    proc = run_goflow(
        "estimate",
        "--data",
        str(data),
        "--method",
        "dropo",
        "--sim-budget",
        "640",
        METHOD_OPTION,
        "samples=10",
        METHOD_OPTION,
        "transitions=8",
        "--out",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    assert "estimate dropo" in proc.stderr and "640/640" in proc.stderr  # tqdm bar over simulator calls
    doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the estimate file"))
    details = doc["info"]["details"]
    assert doc["info"]["sim_calls"] == 640 and details["generations"] == 1
    assert np.isfinite(details["best_objective"])


def test_non_finite_method_option_is_one_line(tmp_path, small_data, run_goflow):
    data, _ = small_data
    # beta=nan: the command; epsilon=abc reaches DROPOConfig (it used to fail deep in numpy)
    for method, option in (("nfpde-softmax", "beta=nan"), ("dropo", "epsilon=abc")):
        out = tmp_path / "est.json"
        proc = run_goflow("estimate", "--data", str(data), "--method", method, METHOD_OPTION, option, "--out", str(out))
        assert proc.returncode != 0
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and option.split("=")[0] in lines[0] and "expected" in lines[0], proc.stderr
        assert not out.exists()


@pytest.mark.parametrize(
    "method, option, value, message",
    [
        ("nfpde-softmax", "beta", float("nan"), r"NFPDEConfig\.beta = nan; expected a finite number in \(0, "),
        ("nfpde-cai", "tau", "0.1", r"NFPDEConfig\.tau = '0.1'; expected a number"),
        ("nfpde-softmax", "clip", 1.5, r"NFPDEConfig\.clip = 1.5; expected a number in \(0, 1\)"),
        ("dropo", "epsilon", float("nan"), r"DROPOConfig\.epsilon = nan; expected a finite number"),
        ("dropo", "sigma0", float("inf"), r"DROPOConfig\.sigma0 = inf; expected a finite number"),
        ("dropo", "popsize", 1, r"DROPOConfig\.popsize = 1; expected an integer >= 2"),
    ],
)
def test_method_configs_check_their_options(method, option, value, message):
    from goflow_common.errors import InputError
    from learning.estimation.estimate import EstimateConfig

    with pytest.raises(InputError, match=message):
        EstimateConfig(method=method, options={option: value}).method_config()


# Every registered env id: collect takes it or says why not (issue 64); an estimate file as the truth.


def test_every_registered_env_is_collected_or_refused_with_a_reason(tmp_path, run_goflow):
    from assembly.envs import _ENVS
    from assembly.transition import TRANSITION_SIMS
    from learning.estimation.collect import DEFAULT_STEPS, NO_TRANSITIONS

    for env_id in _ENVS:
        assert (env_id in TRANSITION_SIMS) != (env_id in NO_TRANSITIONS), env_id
        assert env_id in NO_TRANSITIONS or env_id in DEFAULT_STEPS, env_id
    assert list(NO_TRANSITIONS) == ["goflow/Toy2D-v0"]
    help_text = " ".join(run_goflow("collect", "--help").stdout.split())
    for env_id in ("goflow/Quadrotor-v0", "goflow/Anymal-v0", "goflow/GearInsertion-v0", "not goflow/Toy2D-v0"):
        assert env_id in help_text, env_id
    out = tmp_path / "no" / "d.npz"
    proc = run_goflow("collect", "--env", "goflow/Toy2D-v0", "--episodes", "2", "--out", out)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "no state dynamics depend on xi" in lines[0], proc.stderr
    assert "goflow/GearInsertion-v0" in lines[0]  # the ids it takes
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize("env_id, state_dim, dim", [("goflow/Anymal-v0", 53, 5), ("goflow/GearInsertion-v0", 44, 3)])
def test_anymal_and_gear_insertion_trajectories_are_collected(env_id, state_dim, dim):
    from learning.estimation.collect import CollectConfig, collect

    ds, truth = collect(CollectConfig(env=env_id, episodes=2, steps=3, seed=0))
    assert ds.num_transitions == 6 and ds.states.shape[1] == state_dim and truth.shape == (2, dim)


def test_quadrotor_collect_estimate_and_recollect_from_the_estimate(tmp_path, run_goflow):
    from learning.estimation.dataset import load_dataset, load_truth
    from learning.estimation.estimate_file import load_estimate
    from learning.estimation.metrics import ot_cost

    data = tmp_path / "q.npz"
    proc = run_goflow(
        "collect", "--env", "goflow/Quadrotor-v0", "--episodes", "4", "--steps", "20", "--seed", "2", "--out", data
    )
    assert proc.returncode == 0, proc.stderr
    estimates = {}
    for method, budget, options in (
        ("nfpde-softmax", 2048, []),
        ("dropo", 640, ["--method-kwarg", "samples=10", "--method-kwarg", "transitions=8"]),
    ):
        out = tmp_path / f"{method}.json"
        proc = run_goflow(
            "estimate", "--data", data, "--method", method, "--sim-budget", budget, *options, "--out", out
        )
        assert proc.returncode == 0, proc.stderr
        estimates[method] = out
    # the DROPO estimate as the truth of a new dataset: its draws are the truth, its source recorded
    again = tmp_path / "again.npz"
    proc = run_goflow(
        "collect", "--env", "goflow/Quadrotor-v0", "--sampler-file", estimates["dropo"], "--episodes", "3",
        "--steps", "5", "--out", again,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    ds = load_dataset(again)
    sampler, doc = load_estimate(estimates["dropo"])
    target = ds.collection["target"]
    assert ds.collection["xi"] == "estimate" and target["file"] == str(estimates["dropo"])
    assert target["method"] == "dropo" and target["distribution"] == sampler.dist.to_dict()
    assert len(target["sha256"]) == 64
    space, truth = load_truth(again)
    assert truth.shape == (3, 1) and np.all(space.contains(truth))
    u_est = space.normalize(sampler.sample(64, np.random.default_rng(0)))
    assert np.isfinite(ot_cost(u_est, space.normalize(truth)))


def test_collect_refuses_a_bad_estimate_file_or_two_sources(tmp_path, run_goflow):
    from assembly.params import Param, ParamSpace
    from learning.estimation.distributions import TruncNormalProduct
    from learning.estimation.estimate_file import save_estimate
    from learning.samplers.estimated import EstimatedSampler

    space = ParamSpace((Param("mass", 0.01, 20.0, "kg"),))  # goflow/Quadrotor-v0's
    good = save_estimate(
        tmp_path / "good.json",
        EstimatedSampler.of(space, TruncNormalProduct(np.array([0.5]), np.array([0.1]))),
        "dropo",
        "goflow/Quadrotor-v0",
        {},
    )
    garbage = tmp_path / "garbage.json"
    garbage.write_bytes(b"PK\x03\x04\x00garbage\xff")
    foreign = tmp_path / "foreign.json"
    foreign.write_text('{"format": "goflow-transitions"}')
    base = ("collect", "--env", "goflow/PointMass-v0", "--episodes", "2", "--steps", "2")
    out = tmp_path / "no" / "d.npz"
    for extra, words in (
        (("--sampler-file", garbage), "invalid JSON"),
        (("--sampler-file", foreign), "not a 'goflow-estimate' file"),
        (("--sampler-file", tmp_path / "missing.json"), "no goflow estimate file"),
        (("--sampler-file", good), "another ParamSpace than goflow/PointMass-v0's"),
        (("--sampler-file", good, "--true-xi", "mixture"), "--true-xi mixture and --sampler-file"),
    ):
        proc = run_goflow(*base, *extra, "--out", out)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], proc.stderr
        assert "pickle" not in lines[0] and "unsafe" not in lines[0]
        assert not (tmp_path / "no").exists()
