"""The simulated controller's lost commands, payload schedule and its own record (``stats()``
and ``--stats-json``), the plant's torque checked against Pinocchio's RNEA."""

import json

import numpy as np
import pytest

from deploy.cli import main
from deploy.simcell.controller import SimController
from deploy.simcell.payload_schedule import parse_schedule
from firmware_bridge.errors import BridgeConfigError
from firmware_bridge.messages import LoadCommand
from iem.errors import PayloadError
from sim.family import default_test_payload, test_payloads
from sim.paths import excitation_path
from sim.payload import Payload, save_payload
from sim.plant import SensorModel
from sim.robot import ArmModel

from .test_sim_controller import Port

TOOL = Payload("tool", 0.73, (0.01, -0.02, 0.06), (2e-3, 1e-4, -2e-4, 3e-3, 3e-4, 1.5e-3))
RECORD_KEYS = {"dropped_commands", "load_in_force", "payload", "applied", "mounted"}


def test_dropped_commands_are_neither_applied_nor_acked_and_later_ones_are():
    port = Port([LoadCommand(1, TOOL)])
    ctl = SimController(port, path=excitation_path(1.0), realtime=False, drop_commands=2)
    ctl.run(cycles=150)
    port.commands = [LoadCommand(2, TOOL)]
    ctl.run(cycles=100)
    assert port.acks == [] and ctl.plant.controller_load is None and ctl.commands == []
    assert {b.load_seq for b in port.beats} == {0}  # the heartbeat says nothing changed
    port.commands = [LoadCommand(3, TOOL)]
    ctl.run(cycles=101)
    assert [(a.seq, a.applied) for a in port.acks] == [(3, True)]
    assert ctl.plant.controller_load is TOOL and port.beats[-1].load_seq == 3
    stats = ctl.stats()
    assert stats["dropped_commands"] == 2 and stats["commands"] == 1
    assert stats["applied"] == [{"t": 0.25, "seq": 3, "mass": TOOL.mass,
                                 "com": list(TOOL.com)}]
    assert stats["load_in_force"]["mass"] == TOOL.mass
    np.testing.assert_allclose(np.reshape(stats["load_in_force"]["inertia"], (3, 3), order="F"),
                               TOOL.inertia_matrix)
    with pytest.raises(BridgeConfigError, match="drop_commands -1: valid is an integer >= 0"):
        SimController(Port(), realtime=False, drop_commands=-1)


def test_the_schedule_swaps_the_payload_at_its_cycle():
    """The measured torque is the RNEA of the payload mounted at each cycle: before the swap
    the first payload's, from cycle 50 (0.05 s) on the second's, and no longer the first's."""
    first, second = default_test_payload(), test_payloads()["test-4w"]
    port = Port()
    ctl = SimController(port, path=excitation_path(1.0), realtime=False,
                        sensor=SensorModel.noiseless(), payload_schedule=[(0.05, second),
                                                                          (0.0, first)])
    model = ArmModel()
    err = {id(first): [], id(second): []}
    for k in range(100):
        ctl.step()
        p = ctl.plant
        for payload in (first, second):
            tau = model.rnea_with_payload(p.last_q, p.last_dq, p.last_ddq, payload.to_phi())
            err[id(payload)].append(float(np.abs(port.states[k].tau_J - tau).max()))
    e1, e2 = np.array(err[id(first)]), np.array(err[id(second)])
    assert e1[:50].max() < 1e-6 and e2[50:].max() < 1e-6
    assert e2[:50].min() > 1e-2 and e1[50:].min() > 1e-2  # the payloads differ in torque
    assert ctl.stats()["mounted"] == [{"t": 0.0, "payload": first.name},
                                      {"t": 0.05, "payload": second.name}]
    assert ctl.payload is first and ctl.plant.payload is second


def test_none_unmounts_and_the_empty_load_is_null():
    port = Port([LoadCommand(1, TOOL)])
    ctl = SimController(port, path=excitation_path(1.0), realtime=False,
                        sensor=SensorModel.noiseless(), payload_schedule=[(0.01, None)])
    ctl.run(cycles=10)
    assert ctl.plant.payload is ctl.payload
    port.commands = [LoadCommand(2, None)]
    ctl.run(cycles=10)
    assert ctl.plant.payload is None
    stats = json.loads(json.dumps(ctl.stats()))  # JSON as written
    assert stats["load_in_force"] is None
    assert [a["seq"] for a in stats["applied"]] == [1, 2]
    assert stats["applied"][1] == {"t": 0.01, "seq": 2, "mass": 0.0, "com": [0.0, 0.0, 0.0]}
    assert stats["mounted"] == [{"t": 0.0, "payload": ctl.payload.name},
                                {"t": 0.01, "payload": None}]
    assert stats["payload"] is None  # the truth at exit: nothing mounted


def test_cli_writes_the_record_to_stats_json(tmp_path):
    tool = tmp_path / "tool.toml"
    save_payload(TOOL, tool)
    out = tmp_path / "stats.json"
    code = main(["sim-controller", "--interface", "virtual", "--channel", "record-cli",
                 "--duration", "0.15", "--drop-commands", "1", "--payload-schedule",
                 f"0:{tool},0.1:none", "--stats-json", str(out)])
    stats = json.loads(out.read_text())
    assert code == 0 and set(stats) >= RECORD_KEYS
    assert stats["mounted"] == [{"t": 0.0, "payload": "tool"}, {"t": 0.1, "payload": None}]
    assert stats["load_in_force"] is None and stats["applied"] == []
    assert stats["dropped_commands"] == 0 and stats["cycles"] == 150


def test_stats_json_holds_the_true_payload_and_what_was_mounted_without_a_schedule(tmp_path):
    """Without --payload-schedule, ``mounted`` holds the payload mounted at the start (it
    was empty), and ``payload`` the true payload at exit in ``load_in_force``'s terms, to
    compare what the plug-in wrote with (it was missing)."""
    tool = tmp_path / "tool.toml"
    save_payload(TOOL, tool)
    out = tmp_path / "stats.json"
    assert main(["sim-controller", "--interface", "virtual", "--channel", "record-truth",
                 "--duration", "0.05", "--payload", str(tool), "--stats-json", str(out)]) == 0
    stats = json.loads(out.read_text())
    assert stats["mounted"] == [{"t": 0.0, "payload": "tool"}]
    truth = stats["payload"]
    assert truth["name"] == "tool" and truth["mass"] == TOOL.mass
    assert truth["com"] == list(TOOL.com)
    np.testing.assert_allclose(np.reshape(truth["inertia"], (3, 3), order="F"),
                               TOOL.inertia_matrix)
    out.unlink()
    assert main(["sim-controller", "--interface", "virtual", "--channel", "record-default",
                 "--duration", "0.05", "--stats-json", str(out)]) == 0
    stats = json.loads(out.read_text())
    default = default_test_payload()
    assert stats["mounted"] == [{"t": 0.0, "payload": default.name}]
    assert stats["payload"]["mass"] == default.mass


@pytest.mark.parametrize(("spec", "wanted"), [
    ("soon", "entry 'soon': valid is comma-separated T:FILE or T:none"),
    ("x:none", "time 'x' is not a number"),
    ("-1:none", "time -1.0: valid is a number of s >= 0"),
    ("0:none,0:none", "time 0 s given twice"),
    ("0:/no/such/tool.toml", "cannot read the payload file: it does not exist"),
])
def test_cli_bad_schedules_exit_2_naming_what_is_valid(spec, wanted, capsys):
    with pytest.raises(SystemExit) as info:
        main(["sim-controller", "--interface", "virtual", f"--payload-schedule={spec}"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "--payload-schedule" in err and wanted in err


def test_cli_bad_drop_count_exits_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["sim-controller", "--interface", "virtual", "--drop-commands=-3"])
    assert info.value.code == 2 and "'-3': valid is an integer >= 0" in capsys.readouterr().err


def test_schedule_spec_parses_files_and_none(tmp_path):
    save_payload(TOOL, tmp_path / "t.toml")
    got = parse_schedule(f" 20:none , 0:{tmp_path / 't.toml'}")
    assert [t for t, _ in got] == [0.0, 20.0] and got[1][1] is None
    assert got[0][1].mass == pytest.approx(TOOL.mass)
    with pytest.raises(PayloadError, match="not a Payload"):
        SimController(Port(), realtime=False, payload_schedule=[(1.0, "tool.toml")])
