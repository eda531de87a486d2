"""``iem bench e2e``'s figures beyond the live run: the estimator's step on the run's own
block points again, back to back (:func:`deploy.bench.timing.step_timing`)."""

from __future__ import annotations

import time

import pytest

from deploy.bench.e2e import _back_to_back, measure
from deploy.bench.timing import MACHINE_LOOP, machine_speed, step_timing
from iem.persistence import load_model


class Stepper:
    """What step_timing needs of an online loop: ``step_block``; keeps what it was given."""

    def __init__(self) -> None:
        self.seen: list = []

    def step_block(self, state):
        self.seen.append(state)
        return state, None


def test_step_timing_steps_every_point_once_in_order():
    stepper = Stepper()
    figures = step_timing(stepper, iter(range(7)))
    assert stepper.seen == list(range(7))
    assert figures["points"] == 7
    assert figures["cpu_mean"] >= 0.0 and figures["p99"] >= figures["median"] >= 0.0


def test_step_timing_paced_leaves_a_period_between_points():
    stepper = Stepper()
    started = time.perf_counter()
    step_timing(stepper, range(5), rate_hz=200.0)
    assert time.perf_counter() - started >= 5 * 0.005 * 0.99  # sleeps never end early
    assert stepper.seen == list(range(5))


def test_step_timing_refuses_no_points():
    with pytest.raises(ValueError, match="at least one block point"):
        step_timing(Stepper(), [])


@pytest.fixture(scope="module")
def measured(trained_phys_model_file) -> dict:
    """The figures of one 1 s ``iem bench e2e`` run, which the tests below read apart."""
    return measure(1.0, model=load_model(trained_phys_model_file), log=lambda *a: None)


def test_bench_e2e_steps_the_same_points_again_back_to_back(measured):
    figures = measured
    step = figures["step_cpu_us"]
    assert figures["cycles"] > 0 and step["points"] == figures["cycles"]
    assert step["live"] > 0.0 and step["back_to_back"] > 0.0
    # the live step is a part of the loop thread's CPU
    loop_us = figures["cpu_share_parts"]["cycle"] * figures["seconds"] / figures["cycles"] * 1e6
    assert step["live"] <= loop_us


def test_machine_speed_times_a_fixed_round_by_cpu_and_wall():
    started = time.perf_counter()
    figures = machine_speed(rounds=200, repeats=3)
    assert set(figures) == {"cpu_us", "wall_us"}
    assert 0.0 < figures["cpu_us"] <= figures["wall_us"] * 1.05  # one thread: CPU <= wall
    # three repeats of 200 rounds, each a round's time: the medians are what was timed
    assert 3 * 200 * figures["wall_us"] * 1e-6 <= (time.perf_counter() - started) * 1.5
    assert MACHINE_LOOP[0] >= 1000 and MACHINE_LOOP[1] >= 3  # medians of enough work
    for bad in ((0, 3), (10, 0)):
        with pytest.raises(ValueError, match="rounds and repeats >= 1"):
            machine_speed(*bad)


def test_bench_e2e_reads_the_machine_speed_beside_the_share(measured):
    f = measured
    m = f["machine_us"]
    assert m["before"]["cpu_us"] > 0.0 and m["after"]["cpu_us"] > 0.0
    round_s = (m["before"]["cpu_us"] + m["after"]["cpu_us"]) / 2.0 * 1e-6
    assert f["cpu_share_rounds"] == pytest.approx(f["cpu_share"] / round_s, rel=1e-12)


def test_a_run_that_estimated_nothing_has_no_back_to_back_figure():
    assert _back_to_back(None, None, []) == {"cpu_mean": None, "points": 0}
