"""``iem bench faults``: the accounting of injected faults, and (slow) a whole run."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from deploy.bench.faults import JOINT_STATE, expected_counters
from firmware_bridge.faults import FaultInjector, FaultSpec

from ..conftest import REPO


def test_expected_counters_follow_each_fault_kind():
    js, hb = JOINT_STATE, "Heartbeat"
    events = [(3, js, "drop"), (5, js, "corrupt"), (5, hb, "corrupt"), (7, js, "duplicate"),
              (9, js, "delay"), (20, js, "silenced"), (21, js, "silenced"),
              # a delay whose next two cycles never arrive: delivered late, not lost
              (30, js, "delay"), (31, js, "drop"), (32, js, "drop"),
              (99, js, "drop")]  # after the last cycle seen: invisible
    got = expected_counters(events, first=0, last=50)
    assert got == {"crc": 2, "duplicate": 1, "out_of_order": 1, "lost": 7}


def test_injector_records_every_fault_with_its_cycle():
    class Codec:
        name = JOINT_STATE

    inj = FaultInjector(FaultSpec(drop=0.2, corrupt=0.1, duplicate=0.1, delay=0.1, seed=4))
    for cycle in range(400):
        inj.apply(Codec, b"\x00" * 8, cycle)
    inj.silence(Codec, 400)
    by = inj.by_message[JOINT_STATE]
    assert sum(1 for e in inj.events if e[2] != "silenced") == sum(
        by[a] for a in ("drop", "corrupt", "duplicate", "delay"))
    assert by["silenced"] == 1 and inj.events[-1] == (400, JOINT_STATE, "silenced")
    assert all(0 <= c <= 400 for c, _, _ in inj.events)


@pytest.mark.slow
@pytest.mark.hil
def test_bench_faults_meets_its_targets(tmp_path):
    """The whole benchmark, short: the service over slcan on a pty with every fault and a
    silence, against a clean run (about a minute)."""
    out = tmp_path / "faults.json"
    proc = subprocess.run([sys.executable, "-m", "deploy.cli", "bench", "faults", "--seconds",
                           "10", "--json", str(out)], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    f = json.loads(out.read_text())
    for key in ("mae_groups_faulty", "mae_groups_clean", "writes", "counters", "injected",
                "counters_match"):
        assert key in f
    assert f["counters_match"], (f["counters"], f["expected"])
    assert f["writes"]["during_silence"] == 0
    assert f["mae_groups_faulty"]["mass"] <= max(1.5 * f["mae_groups_clean"]["mass"], 0.001)
    assert f["writes"]["max_error_mass_kg"] <= 0.01
    assert f["writes"]["max_error_com_m"] <= 0.005
