"""The success classifier behind the constrained mode's feasible set, and the evidence's design
weights that make its rows stand for a uniform design."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from goflow_common.errors import InputError
from learning.samplers.signal_memory import SignalMemory
from learning.samplers.feasibility import SuccessClassifier


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


def _ring(x: np.ndarray) -> np.ndarray:
    r = np.linalg.norm(x - 0.5, axis=1)
    return ((r >= 0.2) & (r <= 0.35)).astype(float)


def _fit(x: np.ndarray, y: np.ndarray, steps: int = 600) -> SuccessClassifier:
    c = SuccessClassifier(2, (64, 64), seed=0)
    c.fit(x, y, np.ones(len(x)), steps=steps, batch=512, lr=3e-3, gen=torch.Generator().manual_seed(0))
    return c


def test_the_classifier_draws_a_ring_from_uniform_rows():
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(8000, 2))
    c = _fit(x, _ring(x))
    test = rng.uniform(size=(20000, 2))
    agree = np.mean((c.probability(test) >= 0.5) == (_ring(test) == 1))
    assert agree >= 0.97, agree


def test_one_class_fits_nothing_and_reads_infeasible():
    c = SuccessClassifier(2)
    x = np.random.default_rng(0).uniform(size=(100, 2))
    assert c.fit(x, np.zeros(100), np.ones(100), steps=5, batch=32, lr=1e-3, gen=torch.Generator()) is None
    assert not c.fitted and np.all(c.probability(x) == 0.0)


def test_a_saved_classifier_reads_the_same_and_a_bad_state_is_refused():
    rng = np.random.default_rng(1)
    x = rng.uniform(size=(2000, 2))
    c = _fit(x, _ring(x), steps=50)
    d = SuccessClassifier(2, (64, 64), seed=5)
    d.load_state_dict(json.loads(json.dumps(c.state_dict())))
    np.testing.assert_array_equal(c.probability(x), d.probability(x))
    with pytest.raises(InputError, match="success classifier state"):
        SuccessClassifier(3).load_state_dict(c.state_dict())


def test_design_weights_give_crowded_rows_less_weight_than_sparse_ones():
    """A sampler's own draws crowd a small disk; the few rows elsewhere must count as a uniform
    batch's would: their weights are larger by about the density ratio (clipped)."""
    rng = np.random.default_rng(2)
    crowd = 0.5 + 0.05 * rng.uniform(-1, 1, size=(4000, 2))
    sparse = rng.uniform(size=(400, 2))
    ev = SignalMemory(2, 10000, 5)
    ev.add(np.concatenate([crowd, sparse]), np.zeros(4400))
    w = ev.design_weights()
    assert np.median(w[4000:]) > 20 * np.median(w[:4000])
    assert w.min() >= 1 / 30 and w.max() <= 30
    uniform = SignalMemory(2, 10000, 5)
    uniform.add(rng.uniform(size=(4000, 2)), np.zeros(4000))
    assert 0.5 <= np.median(uniform.design_weights()) <= 2.0


def test_the_boundary_is_read_from_the_averaged_parameters_and_old_states_load():
    """`probability` reads the steps' moving average, which a state keeps beside the last
    parameters; a state saved before the average existed reads its last parameters."""
    rng = np.random.default_rng(3)
    x = rng.uniform(size=(2000, 2))
    c = _fit(x, _ring(x), steps=50)
    state = json.loads(json.dumps(c.state_dict()))
    assert state["average"] != state["params"]
    del state["average"]
    old = SuccessClassifier(2, (64, 64), seed=5)
    old.load_state_dict(state)
    last = SuccessClassifier(2, (64, 64), seed=5)
    last.load_state_dict({**state, "average": state["params"]})
    np.testing.assert_array_equal(old.probability(x), last.probability(x))
    assert not np.array_equal(old.probability(x), c.probability(x))


def _disk(x: np.ndarray, radius: float = 0.05) -> np.ndarray:
    return (np.linalg.norm(x - 0.5, axis=1) <= radius).astype(float)


def test_the_window_alone_keeps_the_newest_rows():
    rng = np.random.default_rng(4)
    batches = [rng.uniform(size=(300, 2)) for _ in range(5)]
    ev = SignalMemory(2, 1000, 5)
    for x in batches:
        ev.add(x, _disk(x))
    newest = np.concatenate(batches)[-1000:]
    assert ev.kept == 0 and np.array_equal(ev.xi, newest) and np.array_equal(ev.signal, _disk(newest))


def test_rows_on_the_class_boundary_are_kept_beyond_the_window():
    """Uniform batches over a small disk: the window holds the newest rows, and the rows that left
    it with a row of the other class among their nearest stay (every one of them near the disk's
    edge, up to `boundary` of them), so the evidence holds more of the disk's points than the
    window alone; a state round trip keeps the split, and an old state (window only) loads."""
    rng = np.random.default_rng(5)
    window, edge = SignalMemory(2, 2000, 5), SignalMemory(2, 2000, 5, boundary=400)
    batches = [rng.uniform(size=(500, 2)) for _ in range(40)]
    for x in batches:
        window.add(x, _disk(x))
        edge.add(x, _disk(x))
    assert 0 < edge.kept <= 400 and len(edge) == 2000 + edge.kept
    assert np.array_equal(edge.xi[edge.kept :], window.xi)  # the same window
    kept = edge.xi[: edge.kept]
    assert np.abs(np.linalg.norm(kept - 0.5, axis=1) - 0.05).max() < 0.06  # on the edge, not far from it
    assert edge.signal.sum() > window.signal.sum() + 10 and (1 - edge.signal).sum() > (1 - window.signal).sum()
    some = SignalMemory(2, 2000, 5, boundary=10)
    for x in batches:
        some.add(x, _disk(x))
    assert some.kept == 10 and len(some) == 2010 and np.array_equal(some.xi[10:], window.xi)  # capped

    state = json.loads(json.dumps(edge.state_dict()))
    again = SignalMemory(2, 2000, 5, boundary=400)
    again.load_state_dict(state)
    assert again.kept == edge.kept and np.array_equal(again.xi, edge.xi)
    old = SignalMemory(2, 2000, 5, boundary=400)
    old.load_state_dict({"xi": state["xi"][edge.kept :], "signal": state["signal"][edge.kept :]})
    assert old.kept == 0 and np.array_equal(old.xi, window.xi)
    for bad in (-1, len(state["signal"]) + 1, 1.5):
        with pytest.raises(InputError, match="evidence state: kept"):
            SignalMemory(2, 2000, 5, boundary=400).load_state_dict({**state, "kept": bad})
