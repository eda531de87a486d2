"""Training in the learning process: the same learners as inline, hand-overs of the open
bag, a killed process, and no orphan process (synthetic data of :mod:`tests.iem.test_checks`)."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import textwrap

import pytest

from iem.worker import LearningError

from .test_checks import DATA
from .test_ensemble_longrun import PARAMS, fitted, learn, same, weights
from .worker_jobs import gone, wait_gone

POINTS = DATA.train_points() + DATA.further_points()


def state_of(model) -> bytes:
    """Everything the model is, as plain data (learners with their generators' states, the
    open bag's kept samples), but for the mode it trains in."""
    state = model.to_state()
    state["params"].pop("background")
    return pickle.dumps(state)


@pytest.mark.parametrize("close", [False, True])
def test_the_learning_process_trains_bit_for_bit_what_inline_training_does(close):
    inline, child = fitted(), fitted(background=True)
    learn(inline, POINTS)
    learn(child, POINTS)
    assert child._worker.pid is not None and child._worker.pid != os.getpid()
    if close:
        inline.close()
        child.close()
    child.drain()
    assert child.n_bags == inline.n_bags > 2 and child.skipped_points == 0
    assert same(weights(child), weights(inline))
    assert state_of(child) == state_of(inline)
    assert child.learning_cpu_s > 0
    child.stop()


def test_the_open_bag_is_handed_over_by_pickle_and_mode_switch_and_learns_on_as_inline():
    half = len(POINTS) // 2
    inline, child = fitted(), fitted(background=True)
    learn(inline, POINTS[:half])
    learn(child, POINTS[:half])
    assert child.open_bag >= 0
    loaded = pickle.loads(pickle.dumps(child))  # the open bag's state comes from the process
    child.stop()
    assert loaded.open_bag == inline.open_bag and loaded.background
    learn(loaded, POINTS[half:half + 20])
    learn(inline, POINTS[half:half + 20])
    loaded.set_background(False)  # from the process to inline, mid-bag
    learn(loaded, POINTS[half + 20:half + 40])
    learn(inline, POINTS[half + 20:half + 40])
    loaded.set_background(True)  # and back
    learn(loaded, POINTS[half + 40:])
    learn(inline, POINTS[half + 40:])
    loaded.close()
    inline.close()
    loaded.drain()
    assert state_of(loaded) == state_of(inline)
    loaded.stop()


def test_a_killed_learning_process_is_reported_and_the_next_bag_starts_a_new_one():
    model = fitted(background=True)
    learn(model, POINTS[:60])  # a bag opens at the 47th point
    model.drain()
    pid = model._worker.pid
    open_bag = model.open_bag
    assert open_bag >= 0
    before = model.learner(open_bag)
    os.kill(pid, signal.SIGKILL)
    assert wait_gone(pid)
    learn(model, POINTS[60:100])  # the open bag's points: lost, or no longer sent
    with pytest.raises(LearningError, match=rf"pid {pid}\).*exit code -9"):
        model.drain()
    model.drain()  # reported once
    assert model.learner(open_bag) is before  # the open bag keeps its last learner
    n = model.n_bags
    learn(model, POINTS[100:])  # another opens at the 174th
    model.close()
    model.drain()
    new_pid = model._worker.pid
    assert new_pid is not None and new_pid != pid and not gone(new_pid)
    assert model.learner(open_bag) is before  # it learnt no more
    assert model.n_bags > n  # later bags were trained in the new process: their refits
    for bag in range(n, model.n_bags):  # (seeded [seed, bag, 3]) landed
        assert model.learner(bag).seed == [PARAMS["seed"], bag, 3]
    model.stop()
    assert wait_gone(new_pid)


def test_stop_ends_the_learning_process():
    model = fitted(background=True)
    learn(model, DATA.further_points()[:5])
    pid = model._worker.pid
    model.stop()
    assert model._worker.pid is None and wait_gone(pid)
    learn(model, DATA.further_points()[5:10])  # a later learn starts another
    assert model._worker.pid not in (None, pid)
    model.stop()


@pytest.mark.parametrize("how", ["exit", "kill"])
def test_no_learning_process_outlives_its_parent(how, tmp_path):
    script = textwrap.dedent(f"""
        import os, sys, time
        sys.path.insert(0, {os.getcwd()!r})
        from tests.iem.test_ensemble_longrun import fitted, learn
        from tests.iem.test_checks import DATA
        model = fitted(background=True)
        learn(model, DATA.further_points()[:5])
        model.drain()
        print(model._worker.pid, flush=True)
        sys.stdin.readline()  # then "exit" ends without stop()
        if {how!r} == "kill":
            time.sleep(600)
        """)
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                              stdin=subprocess.PIPE, text=True)
    try:
        pid = int(parent.stdout.readline())
        assert not gone(pid)
        parent.stdin.write("go\n")
        parent.stdin.flush()
        if how == "kill":
            parent.kill()
        parent.wait(60)
        assert wait_gone(pid)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
