"""The offline dataset format: round trip, and the reader's refusals with clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from learning.estimation.collect import CollectConfig, collect
from learning.estimation.dataset import DatasetError, load_dataset, load_truth, save_dataset


@pytest.fixture(scope="module")
def small():
    return collect(CollectConfig(env="goflow/PointMass-v0", xi="mixture", episodes=4, steps=10, seed=3))


def _arrays(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _write(path, arrays):
    np.savez_compressed(path, **arrays)
    return path


def test_round_trip_and_truth_kept_apart(tmp_path, small):
    ds, truth = small
    path = save_dataset(tmp_path / "d.npz", ds, truth)
    back = load_dataset(path, expected_space=ds.space)
    assert back.env_id == "goflow/PointMass-v0" and back.num_episodes == 4 and back.num_transitions == 40
    np.testing.assert_array_equal(back.next_states, ds.next_states)
    assert not hasattr(back, "true_xi")  # estimators never see the truth
    space, true_xi = load_truth(path)
    assert space == ds.space
    np.testing.assert_array_equal(true_xi, truth)
    assert back.collection["xi"] == "mixture" and back.collection["policy"] == "random"
    meta = json.loads(str(_arrays(path)["meta"]))
    assert [p["unit"] for p in meta["params"]] == ["kg", "N s/m"]


def test_logged_transitions_replay_exactly(small):
    from assembly.transition import make_transition_sim

    ds, truth = small
    sim = make_transition_sim(ds.env_id)
    pred = sim.step(ds.states, ds.actions, truth[ds.episode])
    np.testing.assert_allclose(pred, ds.next_states, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda a: a.pop("actions"), "missing array(s) ['actions']"),
        (lambda a: a.__setitem__("next_states", a["next_states"][:-1]), "'next_states' has shape"),
        (
            lambda a: a["states"].__setitem__((3, 1), np.nan),
            "'states' has 1 non-finite value(s) (first: row 3, column 1",
        ),
        (lambda a: a.__setitem__("episode", a["episode"][::-1].copy()), "non-decreasing"),
        (lambda a: a.__setitem__("true_xi", a["true_xi"][:2]), "'true_xi' has shape (2, 2), expected (4, 2)"),
        (lambda a: a.__setitem__("meta", np.array("{not json")), "'meta' is not valid JSON"),
        (lambda a: a.__setitem__("meta", np.array(json.dumps({"format": "other"}))), "format/version is 'other'"),
        (lambda a: a["true_xi"].__setitem__((0, 0), 99.0), "parameter 'mass' = 99 kg is outside its bounds"),
    ],
)
def test_reader_rejects_malformed(tmp_path, small, mutate, message):
    ds, truth = small
    good = save_dataset(tmp_path / "good.npz", ds, truth)
    arrays = _arrays(good)
    mutate(arrays)
    bad = _write(tmp_path / "bad.npz", arrays)
    with pytest.raises(DatasetError) as info:
        load_dataset(bad)
    assert message in str(info.value) and "bad.npz" in str(info.value)


def test_reader_rejects_missing_garbage_and_wrong_params(tmp_path, small):
    ds, truth = small
    with pytest.raises(DatasetError, match="no such file"):
        load_dataset(tmp_path / "nope.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match="not a readable .npz"):
        load_dataset(tmp_path / "junk.npz")
    good = save_dataset(tmp_path / "good.npz", ds, truth)
    from assembly.transition.cartpole import CartpoleTransitionSim  # noqa: F401 (import only)
    from assembly.envs.cartpole import CARTPOLE_SPACE

    with pytest.raises(DatasetError, match="parameters differ from the simulator's.*parameter names differ"):
        load_dataset(good, expected_space=CARTPOLE_SPACE)
    meta = json.loads(str(_arrays(good)["meta"]))
    meta["params"][0]["name"] = "mass"
    meta["params"][1]["name"] = "mass"
    arrays = _arrays(good)
    arrays["meta"] = np.array(json.dumps(meta))
    with pytest.raises(DatasetError, match="bad parameter list.*duplicate"):
        load_dataset(_write(tmp_path / "dupe.npz", arrays))


def test_writer_refuses_bad_truth(tmp_path, small):
    ds, truth = small
    with pytest.raises(DatasetError, match="'true_xi' has shape"):
        save_dataset(tmp_path / "x.npz", ds, truth[:, :1])


def test_actions_outside_the_unit_box_are_refused_on_save_and_load(tmp_path, small):
    import dataclasses

    ds, truth = small
    arrays = _arrays(save_dataset(tmp_path / "good.npz", ds, truth))
    arrays["actions"][5, 0] = 1.5
    arrays["actions"][7, 0] = -3.0
    bad = _write(tmp_path / "bad.npz", arrays)
    message = r"'actions' has 2 value\(s\) outside \[-1, 1\] \(first: row 5, column 0 = 1.5\); expected normalized"
    for read in (load_dataset, load_truth):
        with pytest.raises(DatasetError, match=message):
            read(bad)
    wild = dataclasses.replace(ds, actions=np.where(np.arange(ds.num_transitions)[:, None] == 3, 2.0, ds.actions))
    with pytest.raises(
        DatasetError, match=r"'actions' has \d+ value\(s\) outside \[-1, 1\] \(first: row 3, column 0 = 2\)"
    ):
        save_dataset(tmp_path / "wild.npz", wild, truth)
    assert not (tmp_path / "wild.npz").exists()
