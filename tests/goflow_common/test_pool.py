"""goflow_common.pool: results in call or finish order, a raising call and a dead worker reported
as a WorkerError naming the call (never a hang), retries, and workers built once by the initializer."""

import os

import pytest

from goflow_common.pool import ProcessPool, WorkerError, map_calls

_STATE = {}


def _remember(value):
    _STATE["value"] = value


def _recall(offset):
    return _STATE["value"] + offset


def test_results_come_back_in_call_order():
    assert map_calls(int, [("3",), ("1",), ("2",)], workers=2) == [3, 1, 2]
    assert map_calls(int, [], workers=2) == []


def test_a_raising_call_is_named():
    with pytest.raises(WorkerError, match=r"call 1 of int: ValueError: invalid literal") as err:
        map_calls(int, [("1",), ("x",)], workers=2)
    assert err.value.index == 1 and err.value.pid is None and isinstance(err.value.__cause__, ValueError)


def test_a_dead_worker_is_retried_then_reported():
    starts = []
    with ProcessPool(2) as pool:
        ((index, error),) = pool.imap(os._exit, [(3,)], retries=1, errors="return", on_start=starts.append)
        assert index == 0 and isinstance(error, WorkerError) and error.attempts == 2 and error.pid is not None
        assert "worker process" in str(error) and starts == [0, 0]
        assert pool.map(abs, [(-1,), (-2,)]) == [1, 2]  # the pool goes on with fresh workers


def test_the_initializer_builds_each_worker_once():
    with ProcessPool(2, _remember, (10,)) as pool:
        assert pool.map(_recall, [(1,), (2,)]) == [11, 12]
        assert sorted(v for _, v in pool.imap(_recall, [(3,), (4,)])) == [13, 14]


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="workers"):
        ProcessPool(0)
    with ProcessPool(1) as pool, pytest.raises(ValueError, match="errors"):
        list(pool.imap(abs, [(1,)], errors="ignore"))
