"""The service's lifecycle and what each run counts: configure, activate, deactivate, shut
down, each state with what it holds open; a run's counters are its own; a silence is a
silence (not the service falling behind), on the run's one clock; the status line shows no
centre of mass where the mass cannot be told from zero; and every failure of a service is
kept in order, the first first.

The controller is the simulated one on the virtual bus, in this process
(:func:`deploy.simcell.inprocess.simulated_cell`).
"""

from __future__ import annotations

import io
import logging

import pytest

from deploy.config import config_from_dict
from deploy.service.failures import Failures
from deploy.service.status import StatusLine
from firmware_bridge.errors import LinkError
from firmware_bridge.faults import FaultSpec

from ..conftest import cell_config

pytestmark = pytest.mark.hil


class Records(logging.Handler):
    """The ``iem`` loggers' records, kept."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)

    def events(self, name: str) -> list[str]:
        return [r.getMessage() for r in self.records if getattr(r, "event", None) == name]


@pytest.fixture
def records():
    handler, iem = Records(), logging.getLogger("iem")
    level = iem.level
    iem.addHandler(handler)
    iem.setLevel(logging.DEBUG)
    try:
        yield handler
    finally:
        iem.removeHandler(handler)
        iem.setLevel(level)


def _cell(model_file, tag: str, **options):
    from deploy.simcell.inprocess import simulated_cell, virtual_channel
    from sim.paths import new_task_path

    link = {"kind": "virtual", "channel": virtual_channel(tag), "profile": "fd",
            **options.pop("link", {})}
    doc = cell_config(model_file, link, **options.pop("sections", {}))
    return simulated_cell(config_from_dict(doc, where="test"), path=new_task_path(),
                          once=True, seed=1, **options)


def test_each_state_holds_what_it_says_and_each_run_counts_its_own_points(phys_model_file):
    counted = []
    with _cell(phys_model_file, "life") as (ctl, service):
        assert service.lifecycle == "inactive"  # configured: the link open, nothing read
        assert service.reader is None and service.tally is None
        service.on_cycle.append(lambda r: counted.append(r.state.t))
        ctl.start()
        first = service.run(until=lambda: ctl.cycles >= 1500)
        assert service.lifecycle == "inactive" and service.reader is None
        n_first = len(counted)
        service.activate()
        assert service.lifecycle == "active" and service.reader is not None
        service.deactivate()
        assert service.lifecycle == "inactive" and service.reader is None
        second = service.run(until=lambda: ctl.cycles >= 3000)
    assert service.lifecycle == "finalized"
    with pytest.raises(LinkError, match="closed"):  # shut down: the link is closed
        service.link.read(0.01)
    with pytest.raises(RuntimeError, match="cannot activate while finalized"):
        service.run()
    assert first["cycles"] == n_first > 0
    assert second["cycles"] == len(counted) - n_first > 0  # its own, not both runs'
    assert 0 < second["wall_s"] < first["wall_s"] + 5.0
    assert not service.failures


def test_a_silent_controller_is_not_the_service_falling_behind(phys_model_file, records):
    """A silence of 0.6 s that starts mid-block closes the open block 0.6 s after its last
    frame: the service must not read that as having fallen behind (past 0.25 s here, which a
    loaded machine's hiccup does not reach)."""
    with _cell(phys_model_file, "quiet", link={"silence_timeout_s": 0.6},
               sections={"estimate": {"max_lag_s": 0.25}},
               faults=FaultSpec(silence_at=1.5035, silence_for=1.5)) as (ctl, service):
        ctl.start()
        summary = service.run(until=lambda: ctl.cycles >= 4000)
    assert summary["silences"] == 1 and records.events("controller_silent")
    assert not records.events("behind")
    assert summary["unlearnt"] == 0


def test_a_run_on_the_controllers_clock_keeps_to_it_through_a_silence(phys_model_file):
    """A run whose gate decides on the controller's clock gives it that clock's time at a
    silence too (the last frame's time plus the silence timeout), never this PC's
    monotonic clock."""
    times, stamps = [], []
    with _cell(phys_model_file, "clock", link={"silence_timeout_s": 0.3},
               faults=FaultSpec(silence_at=1.5035, silence_for=1.0)) as (ctl, service):
        service.gate_clock = "controller"
        step = service.gate.step

        def step_and_record(t, *args, **kwargs):
            times.append(t)
            return step(t, *args, **kwargs)

        service.gate.step = step_and_record  # the one way in: points and silences
        service.on_cycle.append(lambda r: stamps.append(r.state.t))
        ctl.start()
        summary = service.run(until=lambda: ctl.cycles >= 3500)
    assert summary["silences"] == 1 and times
    assert stamps[0] <= min(times) and max(times) <= stamps[-1], (min(times), max(times))
    before = max(t for t in stamps if t < 1.6)
    assert any(abs(t - (before + 0.3)) < 0.02 for t in times), before  # the silence's own


def test_no_centre_of_mass_on_the_status_line_while_the_mass_cannot_be_told_from_zero(
        phys_model_file):
    """A bare flange (nothing mounted), then a restart from the model it saved: the mass
    is zero within its band, and its CoM is noise over noise."""

    def bare_run(seconds: float) -> list[str]:
        stream = io.StringIO()
        with _cell(phys_model_file, "bare", payload_schedule=[(0.0, None)],
                   status=StatusLine(True, stream, 0.25, plain_period_s=0.3)) as (ctl, service):
            ctl.start()
            service.run(until=lambda: ctl.cycles >= seconds * 1000)
        return [line for line in stream.getvalue().splitlines() if " kg " in line]

    lines = bare_run(2.0) + bare_run(1.0)  # the second from the first's saved model
    assert len(lines) >= 4, lines
    for line in lines:
        mass = line.split("  m ")[1].split(" kg")[0]
        m, band = (float(v) for v in mass.split("±"))
        assert (" c [" in line) == (m - band > 0.0), line
    assert any(" c -" in line for line in lines[-2:]), lines  # bare: m within its band


def test_failures_are_kept_in_order_and_every_step_runs():
    failures, ran = Failures(), []

    def fails(message: str):
        def step() -> None:
            ran.append(message)
            raise OSError(message)
        return step

    with pytest.raises(OSError, match="receive"):
        failures.run_all([("reading", fails("receive")), ("closing", fails("close")),
                          ("saving", lambda: ran.append("save"))])
    assert ran == ["receive", "close", "save"]
    assert str(failures.first) == "receive"
    assert [(stage, str(e)) for stage, e in failures.follow_ons] == [("closing", "close")]
    failures.run_all([("closing again", fails("again"))])  # a follow-on: not raised
    assert [stage for stage, _ in failures.follow_ons] == ["closing", "closing again"]
    failures.add("reading", failures.first)  # the same error twice is one failure
    assert len(failures) == 3
