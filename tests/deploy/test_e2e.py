"""The plug-in end to end: identification and write-back over a bus, restart, faults.

Hardware in the loop here means the simulated controller (the MuJoCo plant at 1 kHz in real
time) behind a real python-can bus or link: the virtual bus in this process, and slcan over a
pty with the controller in another process.
"""

from __future__ import annotations

import json
import logging
import shutil
import signal

import numpy as np
import pytest

from deploy.config import config_from_dict, load_config
from deploy.service.loop import Service
from deploy.service.status import StatusLine
from iem.metrics import mae_groups
from iem.persistence import load_model
from sim.family import default_test_payload

from .conftest import (
    cell_config,
    controller_process,
    new_task_csv,
    service_process,
    stop_process,
    wait_for,
    write_toml,
)

pytestmark = pytest.mark.hil

TRUTH = default_test_payload()

MASS_TOL_KG = 0.002
COM_TOL_M = 0.002
"""How far IEM+phys, the deployed model, may be from the truth here, in the final estimate
and in every load written. docs/benchmarks.md: ``iem demo`` leaves the controller's load
0.3 g and 0.1 mm off, ``iem bench faults`` writes loads within 0.3-0.7 g; the claim is
about 1 g. These runs measured 0.2 g and 0.05 mm (final estimate), 0.2-0.4 g and 0.4-0.8 mm
(loads written, clean and faulty). Margin: twice the 1 g claim, and 2 mm, 2.5 times the
worst CoM measured."""

IEM_MASS_TOL_KG = 0.010
"""The same for the paper's IEM, which has no physics behind it: docs/benchmarks.md gives
its mass MAE on the new path as 0.005 kg; the slcan runs here measured 0.7-3.3 g (final
estimate) and 0.6-0.9 g (load in force). Margin: twice the benchmark."""


def run_in_process(model_file, *, faults=None, seconds=7.0, gate=None, path=None, seed=1,
                   estimate=None):
    """The simulated controller (new task path, once) and the service on one virtual bus.

    The service works on ``model_file`` and saves it at the end; give each run its own copy.
    Returns the service summary, the controller, and the smoothed estimates per cycle.
    """
    from deploy.simcell.inprocess import simulated_cell, virtual_channel
    from sim.paths import new_task_path

    doc = cell_config(model_file, {"kind": "virtual", "channel": virtual_channel("test"),
                                   "profile": "fd"}, gate=gate or {}, estimate=estimate or {})
    rows = []
    with simulated_cell(config_from_dict(doc, where="test"), path=path or new_task_path(),
                        payload=TRUTH, once=True, seed=seed, faults=faults) as (controller,
                                                                                service):
        service.on_cycle.append(lambda r: rows.append((r.state.t, r.smoothed.copy())))
        controller.start()
        summary = service.run(until=lambda: controller.cycles >= seconds * 1000)
    t = np.array([r[0] for r in rows])
    est = np.array([r[1] for r in rows])
    return summary, controller, t, est


def assert_identified_and_acknowledged(summary, controller, est) -> None:
    # identified: the smoothed estimate at the end is the true payload
    final = est[-1]
    assert abs(final[0] - TRUTH.mass) < MASS_TOL_KG, final[0]
    np.testing.assert_allclose(final[1:4] / final[0], TRUTH.com, atol=COM_TOL_M)
    # written back and acknowledged (a write sent just before the run ended may still be in
    # flight); the controller now uses (close to) the true load
    sent, acked = summary["writes"]["sent"], summary["writes"]["acked"]
    assert sent >= 1 and sent - 1 <= acked <= sent
    assert summary["writes"]["refused_by_controller"] == 0
    applied = [cmd for cmd, ok in controller.commands if ok]
    assert acked <= len(applied) <= sent
    load = controller.plant.controller_load
    assert load is not None and abs(load.mass - TRUTH.mass) < MASS_TOL_KG, load
    np.testing.assert_allclose(load.com, TRUTH.com, atol=COM_TOL_M)


def test_identifies_and_writes_back_over_the_virtual_bus(phys_model_file):
    model_file = phys_model_file
    initial_bags = load_model(model_file).n_bags
    summary, controller, _, est = run_in_process(model_file)
    assert summary["model"] == "IEM+phys"
    assert_identified_and_acknowledged(summary, controller, est)
    assert summary["frames"]["lost"] == 0
    assert summary["bags"] > initial_bags  # the new task formed bags
    assert load_model(model_file).n_bags == summary["bags"]  # saved at close


def test_identifies_and_writes_back_over_slcan_on_a_pty(model_file, tmp_path):
    """The controller in another process acts as an slcan adapter; the service opens it with
    python-can's own slcan interface (classic profile: 500 joint states per second).

    The paper's IEM: IEM+phys is made for 100 block points a second and the classic profile
    gives 50. The IEM reports no uncertainty, so the gate is told to let it write: this test
    is about the link."""
    csv = new_task_csv(tmp_path / "path.csv")
    with controller_process("--interface", "slcan-pty", "--profile", "classic", "--path",
                            str(csv), "--once", "--duration", "12", "--seed", "1") as (proc, pty):
        doc = cell_config(model_file, {"kind": "slcan", "channel": pty, "profile": "classic",
                                       "silence_timeout_s": 0.5},
                          gate={"allow_without_uncertainty": True})
        service = Service(config_from_dict(doc, where="test"), status=StatusLine(False))
        rows = []
        service.on_cycle.append(lambda r: rows.append(r.smoothed.copy()))
        try:
            service.open()
            assert service.rate_hz == 500.0
            summary = service.run(duration=8.0)
        finally:
            service.close()
        _, err = stop_process(proc)
    # python-can's slcan reads a byte per call: the service reads fewer than the 500 states
    # per second the controller publishes (see README); block points of 10 of them
    assert summary["cycles"] > 100, summary
    assert summary["frames"]["received"] >= 10 * (summary["cycles"] - 1)
    parts = summary["cpu_parts"]  # the plug-in's CPU, by thread
    assert parts["cycle"] > 0 and parts["reader"] > 0
    assert summary["cpu_s"] == pytest.approx(sum(parts.values()))
    assert 0.0 < summary["step_cpu_s"] <= parts["cycle"]  # the estimator's part of the loop
    final = rows[-1]
    assert abs(final[0] - TRUTH.mass) < IEM_MASS_TOL_KG, final[0]
    assert summary["writes"]["sent"] >= 1 and summary["writes"]["acked"] >= 1
    load = summary["load_in_force"]
    assert summary["load_in_force_confirmed"] and isinstance(load, dict), summary
    assert abs(load["mass"] - TRUTH.mass) < IEM_MASS_TOL_KG, load
    assert "commands" in err  # the controller's closing statistics


def test_restart_after_sigkill_resumes_from_the_last_checkpoint(model_file, tmp_path):
    csv = new_task_csv(tmp_path / "path.csv")
    initial = load_model(model_file)
    with controller_process("--interface", "slcan-pty", "--profile", "classic", "--path",
                            str(csv), "--duration", "40") as (_, pty):
        doc = cell_config(model_file, {"kind": "slcan", "channel": pty, "profile": "classic",
                                       "silence_timeout_s": 0.5},
                          model={"checkpoint_period_s": 1.0})
        config = write_toml(tmp_path / "cell.toml", doc)
        load_config(config)  # the file is a valid configuration

        def checkpointed_with_new_bags():
            try:
                m = load_model(model_file)
            except Exception:
                return None
            return m if m.n_bags > initial.n_bags else None

        first = service_process(config)
        try:
            checkpoint = wait_for(checkpointed_with_new_bags, timeout=30)
            assert checkpoint is not None, "no checkpoint with new bags within 30 s"
            first.send_signal(signal.SIGKILL)
            first.wait(10)
        finally:
            stop_process(first)
        # the file the killed service left is complete (saves are atomic)
        before = load_model(model_file)
        assert before.n_bags >= checkpoint.n_bags > initial.n_bags
        second = service_process(config, "--duration", "4")
        try:
            second.wait(30)
        finally:
            _, logs = stop_process(second)
    events = [json.loads(line) for line in logs.splitlines() if line.startswith("{")]
    loaded = [e for e in events if e.get("event") == "model_loaded"]
    assert loaded and loaded[0]["bags"] == before.n_bags
    after = load_model(model_file)
    assert after.n_bags >= before.n_bags
    # nothing older is lost: every bag is there and every closed bag's learner is as it was
    # (bag means keep moving as points join them: Algorithm 1)
    for bag in range(before.n_bags):
        if bag == before.open_bag:
            continue  # the bag being formed at the checkpoint may go on learning
        np.testing.assert_array_equal(after.learner(bag).a, before.learner(bag).a)
        np.testing.assert_array_equal(after.learner(bag).b, before.learner(bag).b)


def test_faults_cost_little_accuracy_and_every_bad_frame_is_counted(phys_model_file, tmp_path):
    """IEM+phys, as ``iem bench faults`` runs it, with the gate as shipped."""
    from firmware_bridge.faults import FaultSpec

    model_file = phys_model_file
    second = tmp_path / "second.msgpack"
    shutil.copyfile(model_file, second)  # both runs start from the same trained model
    # learning inline and always (max_lag_s 0): with the worker, or with learning skipped
    # while the service is behind, what is learnt at an instant depends on the host, not on
    # the stream, and this compares the stream's cost
    inline = {"background_learning": False, "max_lag_s": 0.0}
    _, clean_controller, _, est_clean = run_in_process(model_file, estimate=inline)
    faulty, controller, _, est_faulty = run_in_process(
        second, faults=FaultSpec(drop=0.05, corrupt=0.01, duplicate=0.02, delay=0.02, seed=3),
        estimate=inline)
    truth = TRUTH.to_phi()
    m_clean, m_faulty = mae_groups(est_clean, truth), mae_groups(est_faulty, truth)
    for g in ("mass", "com", "inertia"):
        assert m_faulty[g] <= 1.5 * m_clean[g], (g, m_clean, m_faulty)
    injector = controller.port.faults
    counts = injector.counts
    assert counts["drop"] > 200 and counts["corrupt"] > 30
    dropped = faulty["frames"]["dropped"]
    assert dropped.get("crc", 0) == counts["corrupt"]  # every corrupted frame, of any kind
    assert dropped.get("malformed", 0) == 0
    # each dropped or corrupted joint-state frame costs its cycle and nothing else (a bad
    # frame among the last few cycles, after the service stopped reading, is not seen)
    joint_state_id = controller.port.profile.joint_state.parts[0].frame_id
    bad_states = sum(1 for key, action in injector.log
                     if action in ("drop", "corrupt", "delay") and key.frame_id == joint_state_id)
    assert bad_states - 3 <= faulty["frames"]["lost"] <= bad_states
    assert dropped.get("duplicate", 0) >= 0.9 * counts["duplicate"]  # (heartbeat repeats are
    # not counted: a heartbeat carries no cycle to assemble)
    # every load written, on the clean stream and the faulty one, is the true payload
    for ctl in (clean_controller, controller):
        loads = [cmd.load for cmd, ok in ctl.commands if ok]
        assert loads, "no load applied"
        for p in loads:
            assert abs(p.mass - TRUTH.mass) < MASS_TOL_KG, p
            assert np.linalg.norm(np.subtract(p.com, TRUTH.com)) < COM_TOL_M, p


def test_silent_controller_stops_writes_and_they_resume(phys_model_file, caplog):
    """IEM+phys: its estimates are always consistent, so the gate's decisions during the
    silence say why nothing is written (with the paper's IEM, an inconsistent inertia at
    the instant the controller fell silent made them all ``inconsistent`` instead)."""
    from firmware_bridge.faults import FaultSpec

    caplog.set_level(logging.INFO, logger="iem")
    gate = {"max_rate_hz": 5.0,
            "stable_window_s": 0.2, "stable_mass_kg": 0.05, "stable_com_m": 0.01}
    summary, _, _, _ = run_in_process(
        phys_model_file, faults=FaultSpec(silence_at=3.0, silence_for=1.0), seconds=6.0,
        gate=gate)
    # (a host starved by other jobs can add a short silence of its own: take the one of
    # about the injected length)
    assert summary["silences"] >= 1
    assert summary["gate"].get("controller_silent", 0) >= 1
    messages = [(r.created, r.getMessage()) for r in caplog.records]
    silent = [t for t, m in messages if m.startswith("controller silent")]
    back = [t for t, m in messages if m.startswith("controller back")]
    pairs = [(s, min(b for b in back if b > s)) for s in silent if any(b > s for b in back)]
    silent_at, back_at = max(pairs, key=lambda p: p[1] - p[0])
    assert 0.6 < back_at - silent_at < 1.5  # the silence lasts 1 s of controller time
    sends = [t for t, m in messages if m.startswith("load sent")]
    assert any(t < silent_at for t in sends)
    assert not any(silent_at < t < back_at for t in sends)  # no write while silent
    # decisions resume: the gate ends judging the estimate against the load in force (the
    # load written before the silence is still right: no write is needed after it)
    assert summary["gate_verdict"]["reason"] in ("no_change", "send", "rate_limited"), (
        summary["gate_verdict"], summary["gate"])
    assert summary["load_in_force"] is not None and summary["load_in_force_confirmed"]
