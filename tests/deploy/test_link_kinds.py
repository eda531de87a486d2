"""``iem run`` opens every link kind from a cell.toml through the one registry.

One test per kind, each with the other end real where this machine allows it: the simulated
controller behind the virtual bus, behind an emulated slcan adapter on a pty and behind the
serial link on a pty (in-process threads), a recorded log for ``replay``, the pylibfranka fake
for ``franka``; SocketCAN skips where the kernel has no AF_CAN.
"""

from __future__ import annotations

import itertools
import sys

import pytest

from deploy.cli import main
from deploy.config import LINK_KINDS, load_config
from deploy.model_setup import link_rate
from deploy.sdnotify import Notifier
from deploy.service import Service
from deploy.sim_controller import SimController
from firmware_bridge.controller_port import open_port
from firmware_bridge.links import LINKS, JointStateSource, PayloadSink, rate_hz
from sim.paths import new_task_path
from tests.firmware_bridge import franka_fake
from tests.firmware_bridge.hil import vcan_unavailable

from .conftest import cell_config, write_toml
from .test_replay import record_sim

_channels = itertools.count()


def run_service(tmp_path, model_file, link: dict, seconds: float = 0.6) -> dict:
    """Open the configured link through ``Service.open`` (as ``iem run`` does) and run."""
    config = load_config(write_toml(tmp_path / "cell.toml", cell_config(model_file, link)))
    service = Service(config, notifier=Notifier(environ={}))
    try:
        service.open()
        assert isinstance(service.link, JointStateSource)
        assert isinstance(service.link, PayloadSink) == LINKS[link["kind"]].sink
        assert service.link.rate_hz == link_rate(config)
        summary = service.run(duration=seconds)
    finally:
        service.close()
    return summary


def controller(interface: str, channel: str = ""):
    port, announce = open_port(interface, channel, "fd")
    return SimController(port).start(), announce


def test_the_config_takes_its_kinds_from_the_registry():
    assert tuple(LINKS) == LINK_KINDS
    assert rate_hz("virtual", "classic") == 500.0 and rate_hz("serial", "classic") == 1000.0


@pytest.mark.parametrize(("interface", "kind"), [
    ("virtual", "virtual"), ("slcan-pty", "slcan"), ("serial-pty", "serial")])
def test_a_simulated_controller_behind_each_link(tmp_path, model_file, interface, kind):
    """The virtual bus in this process; slcan and serial on a pty in the controller's."""
    channel = f"kinds-{next(_channels)}" if interface == "virtual" else ""
    sim, pty = controller(interface, channel)
    try:
        summary = run_service(tmp_path, model_file, {"kind": kind, "channel": pty or channel})
    finally:
        sim.close()
    assert summary["cycles"] > 0


def test_socketcan(tmp_path, model_file):
    why = vcan_unavailable()
    if why:
        pytest.skip(why)
    sim, _ = controller("socketcan", "vcan0")
    try:
        summary = run_service(tmp_path, model_file, {"kind": "socketcan", "channel": "vcan0"})
    finally:
        sim.close()
    assert summary["cycles"] > 0


def test_franka_with_the_pylibfranka_fake(tmp_path, model_file, monkeypatch):
    module = franka_fake.module()
    module.Robot = lambda address, config: franka_fake.Robot(address, config, free_running=True)
    monkeypatch.setitem(sys.modules, "pylibfranka", module)
    summary = run_service(tmp_path, model_file, {"kind": "franka", "channel": "172.16.0.2"})
    assert summary["cycles"] > 0


def test_replay_through_iem_run(tmp_path, model_file, capsys):
    """``[link] kind = "replay"`` in cell.toml: ``iem run`` replays the file to its end."""
    log = tmp_path / "cell.log"
    path = new_task_path().slice(0, 0.5)
    record_sim(log, "fd", path=path)
    cell = write_toml(tmp_path / "cell.toml",
                      cell_config(model_file, {"kind": "replay", "channel": str(log)}))
    assert main(["run", "--config", str(cell)]) == 0
    err = capsys.readouterr().err
    assert "iem run: " in err and " cycles" in err
    cycles = int(err.split("iem run: ")[1].split(" cycles")[0])
    assert cycles == -(-len(path) // 10)  # every recorded cycle's block, then the end
