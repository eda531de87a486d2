"""``iem set-load``: one load to the simulated controller on python-can's virtual bus, through
the gate's checks; the controller's plant (what it believes is mounted) is the truth."""

from __future__ import annotations

import itertools
import json
import time

import pytest

from deploy.cli import main
from deploy.simcell.controller import SimController
from firmware_bridge.controller_port import open_port
from iem.payload import Payload
from sim.paths import excitation_path
from sim.payload import save_payload
from tests.fci import STALL_RERUN

from ..conftest import write_toml

pytestmark = pytest.mark.hil
pytest.importorskip("mujoco", reason="the simulated controller needs MuJoCo")

_channels = itertools.count()
TOOL = Payload("tool", 0.73, (0.01, -0.02, 0.06), (2e-3, 1e-4, -2e-4, 3e-3, 3e-4, 1.5e-3))


@pytest.fixture
def cell(tmp_path):
    """``(cell.toml, channel)``: a virtual-bus cell on a channel of its own."""
    channel = f"set-load-{next(_channels)}"
    config = write_toml(tmp_path / "cell.toml", {"link": {"kind": "virtual", "channel": channel},
                                                 "log": {"status_line": "off"}})
    return config, channel


def start_controller(channel: str, **options) -> SimController:
    port, _ = open_port("virtual", channel, "fd")
    return SimController(port, path=excitation_path(1.0), realtime=False, **options).start()


def payload_file(tmp_path, payload: Payload, name: str = "p.toml"):
    path = tmp_path / name
    save_payload(payload, path)
    return path


def test_applied_load_is_in_force_in_the_controller_and_acked(cell, tmp_path, capsys):
    config, channel = cell
    ctl = start_controller(channel)
    try:
        code = main(["set-load", str(payload_file(tmp_path, TOOL)), "--config", str(config),
                     "--json"])
        out = json.loads(capsys.readouterr().out)
    finally:
        ctl.close()
    assert ctl.error is None
    assert code == 0 and out["applied"] and out["error"] == ""
    assert [(c.seq, ok) for c, ok in ctl.commands] == [(out["seq"], True)]
    held = ctl.plant.controller_load
    assert held.mass == pytest.approx(TOOL.mass) and held.com == pytest.approx(TOOL.com)
    assert held.inertia == pytest.approx(TOOL.inertia)
    mass, com, inertia = TOOL.set_load_args()
    assert out["load_in_force"]["mass"] == pytest.approx(mass)
    assert out["load_in_force"]["com"] == pytest.approx(com)
    assert out["load_in_force"]["inertia"] == pytest.approx(inertia)


def test_clear_clears_the_load(cell, tmp_path, capsys):
    config, channel = cell
    ctl = start_controller(channel)
    try:
        assert main(["set-load", str(payload_file(tmp_path, TOOL)), "--config",
                     str(config)]) == 0
        assert ctl.plant.controller_load is not None
        assert main(["set-load", "--clear", "--config", str(config)]) == 0
        out = capsys.readouterr().out.splitlines()
    finally:
        ctl.close()
    assert ctl.plant.controller_load is None
    assert [ok for _, ok in ctl.commands] == [True, True] and ctl.commands[1][0].load is None
    assert "applied" in out[0] and "0.7300 kg" in out[0]
    assert "applied" in out[1] and "in force: none (mass 0)" in out[1]


@pytest.mark.parametrize(("text", "wanted"), [
    ('name = "heavy"\nmass = 5.0\ncom = [0.0, 0.0, 0.05]\n'
     'inertia = [0.01, 0.0, 0.0, 0.01, 0.0, 0.01]\n', "over_rated"),
    ('name = "nan"\nmass = nan\ncom = [0.0, 0.0, 0.05]\n'
     'inertia = [0.01, 0.0, 0.0, 0.01, 0.0, 0.01]\n', "'mass' must be a number"),
    ('name = "flat"\nmass = 1.0\ncom = [0.0, 0.0, 0.05]\n'
     'inertia = [0.001, 0.0, 0.0, 0.001, 0.0, 0.003]\n', "triangle inequality"),
    ('name = "far"\nmass = 1.0\ncom = [0.0, 0.0, 0.4]\n'
     'inertia = [0.01, 0.0, 0.0, 0.01, 0.0, 0.01]\n', "com_too_far"),
], ids=["over_rated", "not_finite", "inconsistent", "com_too_far"])
def test_a_load_the_checks_refuse_is_never_sent(cell, tmp_path, capsys, text, wanted):
    config, channel = cell
    path = tmp_path / "bad.toml"
    path.write_text(text)
    ctl = start_controller(channel)
    try:
        code = main(["set-load", str(path), "--config", str(config)])
        time.sleep(0.3)  # a command sent would have arrived by now
        cycles = ctl.cycles
    finally:
        ctl.close()
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("iem: error: ") and wanted in err
    assert ctl.commands == [] and cycles > 0
    assert ctl.plant.controller_load is None


def test_over_rated_names_the_limit(cell, tmp_path, capsys):
    config, _ = cell
    heavy = Payload("heavy", 3.5, (0, 0, 0.05), (0.01, 0, 0, 0.01, 0, 0.01))
    assert main(["set-load", str(payload_file(tmp_path, heavy)), "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "over_rated" in err and "3.500 kg" in err and "rated 3 kg" in err


def test_a_refusal_by_the_controller_exits_1_with_its_text(cell, tmp_path, capsys):
    config, channel = cell
    ctl = start_controller(channel, refuse_while_moving=True)  # back and forth: always moving
    try:
        code = main(["set-load", str(payload_file(tmp_path, TOOL)), "--config", str(config)])
        out = capsys.readouterr().out
    finally:
        ctl.close()
    assert code == 1
    assert "NOT applied" in out and "command not possible in the current mode" in out
    assert "in force: none (mass 0)" in out
    assert [ok for _, ok in ctl.commands] == [False] and ctl.plant.controller_load is None


def test_no_answer_within_the_timeout_exits_1(cell, tmp_path, capsys):
    config, _ = cell  # no controller on this channel
    code = main(["set-load", str(payload_file(tmp_path, TOOL)), "--config", str(config),
                 "--timeout", "0.3", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 1
    assert out == {"applied": False, "seq": 1, "load_in_force": "unknown",
                   "error": "no answer from the controller to command 1 within 0.3 s"}


@pytest.mark.parametrize("argv", [["--clear", "FILE"], []])
def test_file_and_clear_together_or_neither_is_an_error(cell, capsys, argv):
    config, _ = cell
    assert main(["set-load", *argv, "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("iem: error: give either a payload FILE or --clear")


def test_a_link_that_writes_no_loads_is_an_error(tmp_path, capsys):
    config = write_toml(tmp_path / "cell.toml", {"link": {"kind": "replay",
                                                          "channel": "x.blf"}})
    assert main(["set-load", "--clear", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "kind 'replay' does not write loads" in err and "virtual" in err


class ReportingLink:
    """A sink that never acknowledges; its controller reports the values in force."""

    def __init__(self) -> None:
        self.load_report = None

    def wait_ack(self, seq, timeout=1.0):
        from firmware_bridge.errors import AckTimeout

        time.sleep(timeout)
        raise AckTimeout("no ack")


def test_a_report_of_the_values_after_the_send_confirms_the_load():
    from deploy.commands.set_load import await_answer
    from firmware_bridge.messages import LoadReport

    link = ReportingLink()
    sent_at = time.perf_counter()
    link.load_report = LoadReport(t=sent_at - 1.0, seq=None, load=TOOL, has_values=True)
    out = await_answer(link, 4, TOOL, 0.2, sent_at=sent_at)  # older than the send: no
    assert not out["applied"] and out["load_in_force"] == "unknown"
    link.load_report = LoadReport(t=sent_at + 0.01, seq=None, load=TOOL.with_name("x"),
                                  has_values=True)
    out = await_answer(link, 4, TOOL, 0.2, sent_at=sent_at)
    assert out["applied"] and out["load_in_force"]["mass"] == TOOL.mass
    other = Payload("other", 0.9, TOOL.com, TOOL.inertia)
    link.load_report = LoadReport(t=sent_at + 0.01, seq=None, load=other, has_values=True)
    assert not await_answer(link, 4, TOOL, 0.2, sent_at=sent_at)["applied"]
    link.load_report = LoadReport(t=sent_at + 0.01, seq=4, load=None, has_values=False)
    assert not await_answer(link, 4, TOOL, 0.2, sent_at=sent_at)["applied"]  # a number alone


@STALL_RERUN
def test_against_franky_sim_each_write_and_the_clear_read_back_as_written(tmp_path, capsys):
    """``[link] kind = "franka"`` through pylibfranka against franky-sim's FR3: the load in
    force printed is the one a robot state read after the command reports, equal to the
    written values (to the state's single precision) and to what the robot holds; so is
    the clear. (The answer once came from the newest state before the command: it printed
    ``none`` after a write and the load before after ``--clear``.)"""
    pytest.importorskip("pylibfranka", reason="the franka extra (pylibfranka) is not installed")
    pytest.importorskip("franky_sim", reason="franky-sim is not installed")
    from deploy.simcell import FciSim
    from iem.payload import Payload

    other = Payload("other", 1.34, (0.0, 0.0, 0.072), (3.5e-3, 6.7e-4, -3.7e-4, 3.5e-3,
                                                        3.7e-4, 4.0e-3))
    with FciSim() as scene:
        config = write_toml(tmp_path / "cell.toml", {
            "link": {"kind": "franka", "channel": scene.host, "silence_timeout_s": 0.5},
            "log": {"status_line": "off"}})
        for load in (TOOL, other, None, None, TOOL):
            args = ["--clear"] if load is None else [str(payload_file(tmp_path, load))]
            code = main(["set-load", *args, "--config", str(config), "--json"])
            out = json.loads(capsys.readouterr().out)
            assert code == 0 and out["applied"], out
            held = scene.status()["m_load"]
            if load is None:
                assert out["load_in_force"] is None and held == 0.0
                continue
            force = out["load_in_force"]
            assert force["mass"] == pytest.approx(load.mass, rel=1e-6)
            assert force["com"] == pytest.approx(list(load.com), rel=1e-6, abs=1e-9)
            assert force["inertia"] == pytest.approx(list(load.set_load_args()[2]), rel=1e-5,
                                                     abs=1e-9)
            assert held == pytest.approx(load.mass)
