"""The service's write path against the simulated controller on the virtual bus: a load the
wire cannot carry, and a controller that refuses loads before it accepts one.

The estimator here is a model that always estimates one given load (what is under test is
what the service does with the estimate, not the estimation); the controller, the bus, the
link, its encoder and the acknowledgements are the real ones.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pytest

from deploy.config import config_from_dict
from deploy.writeback.gate import SafetyGate
from firmware_bridge.protocol import LoadAck
from iem.base import BaseEstimator
from iem.types import PayloadEstimate
from sim.family import default_test_payload
from sim.payload import Payload

from ..conftest import cell_config

pytestmark = pytest.mark.hil

TRUTH = default_test_payload()
BAR = Payload("bar", 2.0, (0.0, 0.0, 0.05), (0.6, 0.0, 0.0, 0.001, 0.0, 0.6))
"""Physically possible, within the rating with the hand (0.76 kg) and reach; Ixx beyond the
CAN signal's ±0.524 kg·m²."""


class OneLoad(BaseEstimator):
    """A model that estimates ``load`` at every point (no bags, nothing learnt)."""

    name = "one-load"

    def __init__(self, load: Payload) -> None:
        self.load = load
        self.phi = load.to_phi()

    def params(self) -> dict:
        return {"load": self.load}

    def learn_one(self, x, flange, samples) -> None:
        pass

    def predict_one(self, x, flange, t: float = 0.0) -> PayloadEstimate:
        return PayloadEstimate(t=t, phi=self.phi.copy())

    def predict_many(self, X, F):
        return np.tile(self.phi, (len(X), 1))

    def to_state(self) -> dict:
        return {"phi": self.phi.tolist()}

    @property
    def n_bags(self) -> int:
        return 0

    def nbytes(self) -> int:
        return self.phi.nbytes


def run_cell(tmp_path, model, *, seconds: float, gate: dict | None = None, prepare=None,
             until=None, status=None):
    """The simulated controller (default test payload, new task path) and the service with
    ``model`` on one virtual bus; ``prepare(service)`` runs once the service is open. Stops
    after ``seconds`` of controller time or when ``until(controller, service)`` is true."""
    from deploy.simcell.inprocess import simulated_cell, virtual_channel
    from sim.paths import new_task_path

    doc = cell_config(tmp_path / "model.msgpack",
                      {"kind": "virtual", "channel": virtual_channel("writes"), "profile": "fd"},
                      gate=gate or {})
    with simulated_cell(config_from_dict(doc, where="test"), path=new_task_path(),
                        payload=TRUTH, once=True, seed=1, model=model,
                        status=status) as (controller, service):
        if prepare is not None:
            prepare(service)
        controller.start()
        summary = service.run(until=lambda: controller.cycles >= seconds * 1000 or (
            until is not None and until(controller, service)))
    return summary, controller, service


FAST = {"stable_window_s": 0.2, "max_rate_hz": 5.0}


def test_a_load_beyond_the_wire_is_refused_by_the_gate_and_the_service_runs_on(tmp_path,
                                                                                caplog):
    caplog.set_level(logging.INFO, logger="iem")
    summary, controller, service = run_cell(tmp_path, OneLoad(BAR), seconds=1.5, gate=FAST)
    assert service.gate.wire_check is not None  # built from the CAN link's wire profile
    assert summary["gate"].get("out_of_wire_range", 0) > 10
    assert "send" not in summary["gate"] and summary["writes"]["sent"] == 0
    assert summary["writes"]["rejected"] == summary["gate"]["out_of_wire_range"]
    assert controller.commands == [] and controller.plant.controller_load is None
    assert summary["cycles"] > 100  # ran to the end (block points: 100 per second)
    logged = [r for r in caplog.records if getattr(r, "reason", "") == "out_of_wire_range"]
    assert len(logged) == 1 and "signal Ixx" in logged[0].getMessage()


def test_an_encode_error_in_send_is_counted_logged_and_survived(tmp_path, caplog):
    """Belt and braces: without the gate's wire check, the link's encoder refuses the bar;
    the service counts and logs it and keeps running (no exit, no write)."""
    caplog.set_level(logging.INFO, logger="iem")

    def no_wire_check(service):
        service.gate = SafetyGate(service.gate.config, None, service.gate.motion.regressor)

    summary, controller, _ = run_cell(tmp_path, OneLoad(BAR), seconds=2.0, gate=FAST,
                                      prepare=no_wire_check)
    errors = summary["writes"]["send_errors"]
    assert errors >= 2  # tried again after the rate limit: the loop went on after the first
    assert errors == summary["gate"]["send"] and summary["writes"]["sent"] == 0
    assert controller.commands == [] and summary["cycles"] > 150
    failed = [r for r in caplog.records if getattr(r, "event", "") == "load_send_failed"]
    assert len(failed) == errors and all(r.levelno == logging.ERROR for r in failed)
    assert "does not fit signal Ixx" in failed[0].getMessage()


@dataclass(frozen=True)
class RefusalAck(LoadAck):
    """An acknowledgement with the controller's error text (as the franka link gives)."""

    error: str = ""


class RefusesTwice:
    """The service's link, except that the first two loads are refused (as a Franka refuses
    setLoad while a controller runs) instead of reaching the controller."""

    def __init__(self, link) -> None:
        self.link = link
        self.refused: list[Payload] = []
        self._ack = None

    def __getattr__(self, name):
        return getattr(self.link, name)

    def send(self, payload) -> int:
        if len(self.refused) < 2:
            self.refused.append(payload)
            seq = 200 + len(self.refused)
            self._ack = RefusalAck(seq=seq, applied=False, load=None,
                                   error="command not possible in the current mode")
            return seq
        return self.link.send(payload)

    @property
    def last_ack(self):
        ack = self.link.last_ack
        return ack if ack is not None else self._ack


def test_refused_loads_are_retried_until_the_controller_accepts(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="iem")
    proxies = []

    def refuse_twice(service):
        proxies.append(RefusesTwice(service.link))
        service.link = proxies[0]

    gate = {**FAST, "refusal_retry_s": 0.2, "refusal_retry_max_s": 0.4}
    summary, controller, service = run_cell(
        tmp_path, OneLoad(TRUTH), seconds=6.0, gate=gate, prepare=refuse_twice,
        until=lambda c, s: c.plant.controller_load is not None and s.gate.commands.acked)
    # two refusals, counted and logged with the controller's text, then the load written
    assert len(proxies[0].refused) == 2
    w = summary["writes"]
    assert (w["sent"], w["refused_by_controller"], w["acked"]) == (3, 2, 1)
    assert summary["gate"].get("refused", 0) >= 1  # decisions waiting for the retry
    refusals = [r for r in caplog.records if getattr(r, "event", "") == "load_refused"]
    assert [r.seq for r in refusals] == [201, 202]
    assert all("command not possible in the current mode" in r.getMessage() for r in refusals)
    assert "retry in 0.2 s" in refusals[0].getMessage()
    assert "retry in 0.4 s" in refusals[1].getMessage()  # doubled
    assert [ok for _, ok in controller.commands] == [True]
    load = controller.plant.controller_load
    assert abs(load.mass - TRUTH.mass) < 1e-4
    np.testing.assert_allclose(load.com, TRUTH.com, atol=1e-5)
    last_sent = service.gate.sent_loads[-1][1]
    assert last_sent is not None and abs(last_sent.mass - TRUTH.mass) < 1e-9


def test_off_a_terminal_the_service_writes_plain_status_lines_between_whole_log_lines(
        tmp_path):
    """``iem run ... | tee log``: no carriage return, status lines at their period, every log
    record on a line of its own."""
    import io
    import json

    from deploy.service.logs import setup_logging
    from deploy.service.status import StatusLine

    out = io.StringIO()
    root = logging.getLogger("iem")
    saved = root.handlers[:], root.level, root.propagate
    setup_logging("info", "json", stream=out)
    try:
        summary, _, _ = run_cell(tmp_path, OneLoad(TRUTH), seconds=2.5, gate=FAST,
                                 status=StatusLine(True, out, plain_period_s=0.5))
    finally:
        root.handlers[:], root.level, root.propagate = saved
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    status = [x for x in lines if x.startswith("status: ")]
    records = [json.loads(x) for x in lines if not x.startswith("status: ")]  # all JSON
    assert len(status) >= 2  # every 0.5 s over a run of at least 2.5 s (real time)
    assert all(" kg " in x and "est/s" in x for x in status)
    assert any(r.get("event") == "load_sent" for r in records) and summary["writes"]["sent"]


@pytest.mark.parametrize("profile", ["fd", "classic"])
def test_the_wire_check_comes_from_a_can_link_and_a_serial_link_has_none(profile):
    from deploy.simcell.inprocess import virtual_channel
    from deploy.writeback.wire import wire_check_of
    from firmware_bridge.links import open_link

    can = open_link("virtual", virtual_channel("wire"), profile=profile)
    try:
        check = wire_check_of(can)
        assert check is not None and check(TRUTH) is None
        assert "signal Ixx" in check(BAR)
    finally:
        can.close()
    serial = open_link("serial", "loop://")  # msgpack floats: no ranges to check
    try:
        assert wire_check_of(serial) is None
    finally:
        serial.close()
