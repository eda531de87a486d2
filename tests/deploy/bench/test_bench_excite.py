"""``iem bench excite``: the designed motion's figures and, per seed, what identify and the
live estimate make of it on the realistic plant (a short run: one seed, a 5 s motion,
long enough for the calibration to keep its bare run)."""

import json

import pytest

from deploy.cli import main
from sim.arm import load_arm

pytest.importorskip("mujoco")


KINDS = {"identify+bare", "identify+arm", "live", "identify+arm_motion", "live_arm_motion",
         "identify+arm_known_load", "live_arm_known_load"}


@pytest.mark.slow
def test_bench_excite_prints_the_design_and_every_payloads_figures(tmp_path, capsys):
    out = tmp_path / "excite.json"
    assert main(["bench", "excite", "--seeds", "0", "--seconds", "5", "--json", str(out),
                 "--out", str(tmp_path / "arms")]) == 0
    printed = capsys.readouterr().out
    assert "condition" in printed and "excitation path" in printed
    r = json.loads(out.read_text())
    assert r["design"]["condition"] < r["design"]["condition_of"]["excitation"]
    assert max(r["design"]["dq_peak_share"]) <= 0.75 + 1e-9
    rows = dict(r["seeds"]["0"])
    gain = rows.pop("gain")
    assert {2, 3, 4} <= set(gain["measured"])  # the joints a known load's weight turns
    assert set(rows) == {"test-3w", "light-tool", "offaxis-tool"}
    for row in rows.values():
        assert set(row) == KINDS
        mass, com = row["identify+bare"]
        assert abs(mass) < 0.05 and com < 5.0  # the bare run cancels the arm's error
    assert set(r["met"]) == KINDS
    # the second arm is fitted on the calibration motion and the motion's bare run together
    alone = load_arm(tmp_path / "arms" / "seed0" / "arm.msgpack").report
    both = load_arm(tmp_path / "arms" / "seed0" / "arm-with-motion.msgpack").report
    assert both["segments"] == alone["segments"] + 1
    assert both["duration_s"] > alone["duration_s"] + 3.0
    known = load_arm(tmp_path / "arms" / "seed0" / "arm-known-load.msgpack")
    assert known.gain.tolist() == gain["read"] and known.report["gain"]["payload"] == "test-4w"
