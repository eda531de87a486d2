"""The service on the ros2 link: JointStates at 1 kHz from another process over loopback DDS
(Cyclone on ``lo``, unicast peer 127.0.0.1, no multicast), the estimate on its topics."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 link needs the 'ros2' extra (cyclonedds)")

from deploy.config import config_from_dict
from deploy.service import Service
from firmware_bridge.ros2_dds import cyclone_config, participant, qos
from firmware_bridge.ros2_link import inertia_values
from firmware_bridge.ros2_types import InertiaStamped, topic_name

from .conftest import REPO, cell_config, stop_process

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
                             "--interface", "lo", "--peer", "127.0.0.1"], cwd=REPO,
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
    # every message from the first to the last one read was either delivered or counted lost
    assert c.delivered == service.cycles == len(rows)
    assert c.delivered + c.lost == stamps[-1] - stamps[0] + 1
    assert c.delivered + c.lost <= N and c.malformed == c.stale == c.out_of_order == 0
    assert summary["cycles"] == c.delivered
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
        assert m.header.frame_id == "fr3_link8"
