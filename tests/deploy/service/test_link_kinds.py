"""``iem run`` opens every link kind from a cell.toml through the one registry.

One test per kind, each with the other end real where this machine allows it: the simulated
controller behind the virtual bus, behind an emulated slcan adapter on a pty and behind the
serial link on a pty (in-process threads), a recorded log for ``replay``, the pylibfranka fake
for ``franka``; SocketCAN skips where the kernel has no AF_CAN.

Every kind that writes loads (``LINKS[kind].sink``) runs IEM+phys, the deployed model, with
the gate as shipped (fail-closed), until a load is in force, and is judged by both ends: the
service's summary (a load sent, acknowledged, in force and confirmed by the controller) and
the controller's own record of what it applied and holds, each against the true payload.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from deploy.cli import main
from deploy.config import LINK_KINDS, load_config
from deploy.model.setup import link_rate
from deploy.service.loop import Service
from deploy.service.sdnotify import Notifier
from deploy.simcell.controller import SimController
from firmware_bridge.controller_port import open_port
from firmware_bridge.links import LINKS, JointStateSource, PayloadSink, rate_hz
from sim.family import default_test_payload
from sim.paths import excitation_path, new_task_path
from tests.firmware_bridge import franka_fake
from tests.firmware_bridge.hil import vcan_unavailable

from ..conftest import cell_config, stopped_summary, write_toml
from ..replay.test_replay import record_sim

_channels = itertools.count()

TRUTH = default_test_payload()
"""The payload every simulated controller here carries (SimController's and the fake's)."""

MASS_TOL_KG = 0.003
COM_TOL_M = 0.005
"""How far the load in force may be from the truth. IEM+phys on the ideal plant writes the
payload to about 1 g (docs/benchmarks.md: ``iem demo`` 0.3 g, ``iem bench faults`` 0.3-0.7 g;
this file's runs 0.5-0.8 g): three times the 1 g claim. The CoM of a load written as soon as
the gate lets it is the bench faults target, 5 mm (that bench measured 1.7-4.6 mm; this
file's runs 0.2-1.5 mm)."""

WRITE_DEADLINE_S = 15.0
"""Seconds a sink kind may take to have a load in force before its test fails (the runs here
took under 2 s)."""

SINK_KINDS = tuple(k for k, v in LINKS.items() if v.sink)
"""The kinds that write loads; :data:`WRITE_TESTS` names the test that checks each one's."""

WRITE_TESTS = {"virtual": "test_a_simulated_controller_behind_each_link",
               "slcan": "test_a_simulated_controller_behind_each_link",
               "serial": "test_a_simulated_controller_behind_each_link",
               "socketcan": "test_socketcan", "franka": "test_franka_with_the_pylibfranka_fake",
               "ros2": "test_ros2_service.py", "program": "test_plugin.py"}
"""Where each sink kind's writes are checked (the ros2 link, against its loopback stand-ins,
has a file of its own)."""


def run_service(tmp_path, model_file, link: dict) -> dict:
    """Open the configured link through ``Service.open`` (as ``iem run`` does), with the gate
    as shipped (fail-closed), and run until a load is in force and the controller confirmed
    it (at most ``WRITE_DEADLINE_S``)."""
    doc = cell_config(model_file, link)
    doc["gate"] = {}
    config = load_config(write_toml(tmp_path / "cell.toml", doc))
    service = Service(config, notifier=Notifier(environ={}))
    try:
        service.open()
        assert isinstance(service.link, JointStateSource)
        assert isinstance(service.link, PayloadSink) == LINKS[link["kind"]].sink
        assert service.link.rate_hz == link_rate(config)
        summary = service.run(duration=WRITE_DEADLINE_S, until=lambda: _settled(service))
    finally:
        service.close()
    return summary


def _settled(service) -> bool:
    """A load is in force, confirmed by the controller, and within the tolerance (a load
    outside it does not end the run: the gate may still replace it)."""
    verdict = service.gate.verdict()
    load = verdict["load_in_force"]
    return verdict["in_force_confirmed"] and isinstance(load, dict) and _near_truth(load)


def _near_truth(load: dict) -> bool:
    return abs(load["mass"] - TRUTH.mass) <= MASS_TOL_KG and \
        float(np.max(np.abs(np.subtract(load["com"], TRUTH.com)))) <= COM_TOL_M


def assert_a_load_in_force(summary: dict, held: dict) -> None:
    """The service sent a load, the controller acknowledged it and it is in force, near the
    truth; ``held`` is what the controller itself holds (mass, com, inertia)."""
    writes = summary["writes"]
    assert writes["sent"] >= 1 and writes["acked"] >= 1 and writes["in_force"] >= 1, writes
    assert writes["lost"] == 0 and writes["refused_by_controller"] == 0, writes
    assert writes["send_errors"] == 0, writes
    assert summary["load_in_force_confirmed"], summary
    load = summary["load_in_force"]
    assert isinstance(load, dict) and _near_truth(load), (load, TRUTH)
    # the controller's own record: it holds that load (to the wire's resolution)
    assert held is not None and _near_truth(held), (held, TRUTH)
    assert held["mass"] == pytest.approx(load["mass"], abs=1e-4)
    np.testing.assert_allclose(held["com"], load["com"], atol=1e-4)
    np.testing.assert_allclose(held["inertia"], load["inertia"], atol=1e-4)


def assert_the_controller_applied_it(sim: SimController, summary: dict) -> None:
    stats = sim.stats()
    assert stats["refused"] == 0 and stats["commands"] >= summary["writes"]["acked"]
    assert stats["applied"], stats
    assert stats["applied"][-1]["mass"] == pytest.approx(stats["load_in_force"]["mass"])
    assert_a_load_in_force(summary, stats["load_in_force"])


def controller(interface: str, channel: str = ""):
    port, announce = open_port(interface, channel, "fd")
    return SimController(port).start(), announce


def test_the_config_takes_its_kinds_from_the_registry():
    assert tuple(LINKS) == LINK_KINDS
    assert rate_hz("virtual", "classic") == 500.0 and rate_hz("serial", "classic") == 1000.0


def test_every_sink_kind_has_its_writes_checked():
    """A new kind that writes loads needs a test that checks them."""
    assert set(WRITE_TESTS) == set(SINK_KINDS)
    tests = {name for name in globals() if name.startswith("test_")}
    for kind, where in WRITE_TESTS.items():
        assert where in tests or (Path(__file__).parent / where).is_file(), (kind, where)


@pytest.mark.parametrize(("interface", "kind"), [
    ("virtual", "virtual"), ("slcan-pty", "slcan"), ("serial-pty", "serial")])
def test_a_simulated_controller_behind_each_link(tmp_path, phys_model_file, interface, kind):
    """The virtual bus in this process; slcan and serial on a pty in the controller's."""
    channel = f"kinds-{next(_channels)}" if interface == "virtual" else ""
    sim, pty = controller(interface, channel)
    try:
        summary = run_service(tmp_path, phys_model_file, {"kind": kind, "channel": pty or channel})
    finally:
        sim.close()
    assert summary["cycles"] > 0
    assert_the_controller_applied_it(sim, summary)


def test_socketcan(tmp_path, phys_model_file):
    why = vcan_unavailable()
    if why:
        pytest.skip(why)
    sim, _ = controller("socketcan", "vcan0")
    try:
        summary = run_service(tmp_path, phys_model_file, {"kind": "socketcan", "channel": "vcan0"})
    finally:
        sim.close()
    assert summary["cycles"] > 0
    assert_the_controller_applied_it(sim, summary)


def test_franka_with_the_pylibfranka_fake(tmp_path, fr3_phys_model_file, monkeypatch):
    """The fake robot, an FR3 (libfranka serves no other), sends a state every ms along the
    FR3's excitation path and holds what ``set_load`` gave it, as libfranka's robot does; the
    franka link's arm model is the FR3's."""
    robots = []

    def robot(address, config):
        made = franka_fake.Robot(address, config, free_running=True)
        start = made.path.q[0]  # where the fake put its plant
        made.path = excitation_path(model=made.kinematics)  # long enough (its own is 2 s)
        np.testing.assert_allclose(made.path.q[0], start, atol=1e-12)
        robots.append(made)
        return made

    module = franka_fake.module()
    module.Robot = robot
    franka_fake.install(monkeypatch, module)
    summary = run_service(tmp_path, fr3_phys_model_file,
                          {"kind": "franka", "channel": "172.16.0.2"})
    assert summary["cycles"] > 0
    fake = robots[0]
    assert fake.set_load_calls >= max(1, summary["writes"]["acked"])
    mass, com, inertia = fake.load
    assert_a_load_in_force(summary, {"mass": mass, "com": com, "inertia": inertia})


def test_replay_through_iem_run(tmp_path, model_file, capsys):
    """``[link] kind = "replay"`` in cell.toml: ``iem run`` replays the file to its end."""
    log = tmp_path / "cell.log"
    path = new_task_path().slice(0, 0.5)
    record_sim(log, "fd", path=path)
    cell = write_toml(tmp_path / "cell.toml",
                      cell_config(model_file, {"kind": "replay", "channel": str(log)}))
    assert main(["run", "--config", str(cell)]) == 0
    cycles = stopped_summary(capsys.readouterr().err)["cycles"]
    assert cycles == -(-len(path) // 10)  # every recorded cycle's block, then the end
