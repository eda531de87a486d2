"""``iem bench bridge``: the decode, latency and bus-load figures, written as JSON."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.smoke
def test_bench_bridge_writes_json(tmp_path):
    out = tmp_path / "bridge.json"
    done = subprocess.run([sys.executable, "-m", "deploy.cli", "bench", "bridge", "--cycles",
                           "2000", "--slcan-cycles", "200", "--ros2-cycles", "1000", "--json",
                           str(out)], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    fig = json.loads(out.read_text())
    for key in ("virtual", "slcan_pty"):
        assert fig[key]["cycles_per_s"] > 0
        assert 0 < fig[key]["latency_us"]["p50"] <= fig[key]["latency_us"]["p99"]
    assert set(fig["bus_load"]) == {"fd", "classic"}
    ros2 = fig["ros2"]
    if "skipped" not in ros2:  # the ros2 extra: 1000 messages at 1 kHz, each counted
        assert ros2["lost"] + ros2["delivered"] == 1000, ros2
        assert 0 < ros2["latency_us"]["p50"] <= ros2["latency_us"]["p99"]
    assert "virtual bus" in done.stdout and "slcan over a pty" in done.stdout
