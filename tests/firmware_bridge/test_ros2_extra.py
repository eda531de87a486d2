"""Without the ``ros2`` extra, opening a ros2 link is a clear configuration error."""

from __future__ import annotations

import sys

import pytest

from firmware_bridge.errors import BridgeConfigError
from firmware_bridge.links import LINKS, open_link


def test_ros2_without_cyclonedds_names_the_extra(monkeypatch):
    kind = LINKS["ros2"]
    assert (kind.module, kind.opener) == ("firmware_bridge.ros2_link", "open_ros2_link")
    monkeypatch.setitem(sys.modules, "cyclonedds", None)  # import cyclonedds raises
    with pytest.raises(BridgeConfigError, match=r"pip install 'iem-payload\[ros2\]'"):
        open_link("ros2", "/franka/joint_states", profile="fd", silence_timeout=0.1)
