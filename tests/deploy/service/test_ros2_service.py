"""The service on the ros2 link: JointStates at 1 kHz from another process over loopback DDS
(Cyclone on ``lo``, unicast peer 127.0.0.1, no multicast), the estimate on its topics."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 link needs the 'ros2' extra (cyclonedds)")

from deploy.config import config_from_dict
from deploy.service.loop import Service
from firmware_bridge.ros2_dds import cyclone_config, participant, qos
from firmware_bridge.ros2_link import inertia_values
from firmware_bridge.ros2_types import InertiaStamped, topic_name

from ..conftest import REPO, cell_config, stop_process

pytestmark = pytest.mark.hil

DOMAIN = 95
N = 3000


def test_service_estimates_from_1khz_joint_states_and_publishes(model_file):
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    doc = cell_config(model_file, {"kind": "ros2", "channel": "/franka/joint_states",
                                   "silence_timeout_s": 0.5},
                      ros2={"domain_id": DOMAIN, "interface": "lo", "peers": ["127.0.0.1"],
                            "estimate_topic": "/iem/payload", "estimate_rate_hz": 10.0})
    config = config_from_dict(doc, where="test")
    assert config.link_options()["domain_id"] == DOMAIN
    dp = participant(DOMAIN, cyclone_config("lo", ("127.0.0.1",)))
    estimates = DataReader(dp, Topic(dp, topic_name("/iem/payload"), InertiaStamped),
                           qos=qos(reliable=True, depth=1000))
    service = Service(config, write=False).open()
    rows = {}
    service.on_cycle.append(lambda r: rows.setdefault(round(r.state.t * 1e3), r.smoothed.copy()))
    proc = subprocess.Popen([sys.executable, "-m", "firmware_bridge.ros2_peers", "publish",
                             "--count", str(N), "--rate", "1000", "--domain", str(DOMAIN),
                             "--interface", "lo", "--peer", "127.0.0.1",
                             "--arm", "panda"], cwd=REPO,  # the configured arm model's names
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        summary = service.run(duration=120.0,
                              until=lambda: proc.poll() is not None and service.silent)
    finally:
        out, err = stop_process(proc)
        service.close()
    assert "done 3000" in out, err
    c = service.link.counters
    stamps = sorted(rows)
    # one estimate per block point of 10 frames (a silence closes a block early)
    assert len(rows) == service.tally.cycles == summary["cycles"]
    assert c.delivered // 10 <= service.tally.cycles <= c.delivered // 10 + 1 + c.silences
    # every message from the first to the last one read was either delivered or counted
    # lost: they span the block points' mean times (ms) plus half of the first and the last
    # block (4.5 ms each at most)
    assert 0 <= c.delivered + c.lost - 1 - (stamps[-1] - stamps[0]) <= 10
    assert c.delivered + c.lost <= N and c.malformed == c.stale == c.out_of_order == 0
    # the estimate as published: the service's smoothed estimate at that stamp, in the
    # flange frame of the joints read, about the CoM
    published = [m for m in estimates.take(N=1000) if isinstance(m, InertiaStamped)]
    assert published and len(published) == service.link.published
    for m in published:
        t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        want = inertia_values(rows[round(t * 1e3)])
        i = m.inertia
        np.testing.assert_allclose([i.m, i.com.x, i.com.y, i.com.z, i.ixx, i.ixy, i.ixz,
                                    i.iyy, i.iyz, i.izz], want, rtol=1e-9, atol=1e-12)
        assert m.header.frame_id == "panda_link8"  # the arm model's flange


# without refusals (slow: the run with refusals covers it, and counts what is refused)
@pytest.mark.parametrize("refusals", [pytest.param(0, marks=pytest.mark.slow), 2])
def test_identifies_and_writes_back_through_set_load(model_file, tmp_path, refusals, caplog):
    """The simulated controller (MuJoCo plant at 1 kHz, new task path once) in another
    process behind ROS 2: JointStates on /franka/joint_states and a SetLoad service in
    rmw_cyclonedds's manner; the service identifies the payload and writes it back. With
    refusals, the first writes are refused as a Franka refuses them while moving
    (success=false and libfranka's text): counted, logged with the text, retried."""
    import json

    from firmware_bridge.ros2_peers import REFUSAL
    from sim.family import default_test_payload

    from ..conftest import new_task_csv

    truth = default_test_payload()
    csv = new_task_csv(tmp_path / "path.csv")
    stats = tmp_path / "stats.json"
    doc = cell_config(model_file, {"kind": "ros2", "silence_timeout_s": 0.5},
                      ros2={"domain_id": 99, "interface": "lo", "peers": ["127.0.0.1"]},
                      gate={"refusal_retry_s": 0.2, "refusal_retry_max_s": 0.4})
    service = Service(config_from_dict(doc, where="test")).open()
    client = service.link.set_load
    rows = []
    service.on_cycle.append(lambda r: rows.append(r.smoothed.copy()))
    proc = subprocess.Popen([sys.executable, "-m", "deploy.simcell.ros2_controller",
                             "--domain", "99", "--interface", "lo", "--peer", "127.0.0.1",
                             "--path", str(csv), "--once", "--duration", "11", "--seed", "1",
                             "--refuse-first", str(refusals), "--stats-json", str(stats)],
                            cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        summary = service.run(duration=60.0,
                              until=lambda: proc.poll() is not None and service.silent)
    finally:
        _, err = stop_process(proc)
        service.close()
    assert stats.exists(), err
    controller = json.loads(stats.read_text())
    final = rows[-1]
    assert abs(final[0] - truth.mass) < 0.03
    np.testing.assert_allclose(final[1:4] / final[0], truth.com, atol=0.01)
    sent, acked = summary["writes"]["sent"], summary["writes"]["acked"]
    assert sent >= 1 + refusals and acked >= 1
    assert summary["writes"]["refused_by_controller"] == client.refusals == refusals
    assert client.successes == acked and client.not_written == 0
    logged = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert (refusals == 0) == (not logged)
    assert refusals == 0 or any("set_load" in m and REFUSAL in m for m in logged)
    applied = [mass for mass, ok in controller["applied"] if ok]
    assert len(applied) >= acked
    assert controller["load"] is not None and abs(controller["load"]["mass"] - truth.mass) < 0.03
