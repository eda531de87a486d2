"""The arm's own joint-state rate: detected from a recording's time stamps (or given with
``--rate``), block points at about 100 a second whatever it is, and the whole pipeline
(``iem calibrate``, ``iem train --rate``, ``iem replay``, ``iem identify``) on a 200 Hz
joint-state CSV of the simulated plant.

The plant runs at 1 kHz (:class:`sim.plant.ArmPlant`); every fifth joint state is written,
as a 200 Hz logger would keep them. The plant is equal to its model (the ideal plant), so the
replay's and the identification's payload can be checked against the payload mounted.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from deploy.cli import main
from iem.errors import InvalidInputError
from iem.signals.rate import block_frames_for, check_rate, detect_rate
from sim.family import default_test_payload
from sim.paths import calibration_path, excitation_path
from sim.plant import ArmPlant
from tests.firmware_bridge.test_recordings import write_csv

REPO = Path(__file__).resolve().parents[2]
EVERY = 5
"""Plant cycles (1 ms) per joint state kept: 200 Hz."""
TRUTH = default_test_payload()


def decimated(rollout, path, every: int = EVERY, keep=None):
    """The rollout's every ``every``-th joint state (those of ``keep`` too) as a CSV."""
    idx = np.arange(0, len(rollout.t), every)
    if keep is not None:
        idx = idx[keep[idx]]
    return write_csv(path, rollout.t[idx], rollout.q[idx], rollout.dq[idx], rollout.tau[idx])


@pytest.fixture(scope="module")
def csvs(tmp_path_factory):
    """200 Hz CSVs: the bare arm on the calibration motion, and the paper's test payload and
    the bare arm on a 6 s exciting motion."""
    folder = tmp_path_factory.mktemp("rate")
    motion = excitation_path(6.0, seed=0, period=3.0)
    return {
        "calibration": decimated(ArmPlant(seed=101).follow(calibration_path()),
                                 folder / "calibration.csv"),
        "loaded": decimated(ArmPlant(seed=1, payload=TRUTH).follow(motion),
                            folder / "loaded.csv"),
        "bare": decimated(ArmPlant(seed=2).follow(motion), folder / "bare.csv"),
        "folder": folder,
    }


@pytest.fixture(scope="module")
def pipeline(csvs):
    """``iem calibrate`` then ``iem train --rate 200`` on the 200 Hz CSVs: their exit
    statuses, what they printed and the files they wrote."""
    folder = csvs["folder"]
    arm, model = folder / "arm.msgpack", folder / "model.msgpack"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        out = {"calibrate": main(["calibrate", str(csvs["calibration"]), "--out", str(arm)]),
               "train": main(["train", "--rate", "200", "--noise", "sensor", "--out",
                              str(model)])}
    return {**out, "printed": printed.getvalue(), "arm": arm, "model": model}


def test_the_rate_is_the_median_step_through_jitter_and_gaps():
    rng = np.random.default_rng(0)
    t = np.arange(4000) / 200.0 + rng.uniform(-0.4e-3, 0.4e-3, 4000)  # a logger's jitter
    keep = np.ones(4000, dtype=bool)
    keep[1000:1060] = False  # a 0.3 s gap
    keep[rng.choice(4000, 200, replace=False)] = False  # 5 % lost, here and there
    assert detect_rate(t[keep]) == 200.0
    assert detect_rate(np.arange(50) * 1e-3) == 1000.0  # 1 ms read back as 0.99999... ms
    assert detect_rate([0.0, 0.1, 0.2, 0.3]) == 10.0  # every step a gap: still a rate
    with pytest.raises(InvalidInputError, match="two increasing time stamps"):
        detect_rate([1.0])


def test_block_points_stay_near_100_a_second():
    for rate, frames in ((100, 1), (150, 2), (200, 2), (500, 5), (1000, 10), (80, 1)):
        assert block_frames_for(rate) == frames
    assert check_rate(99.0) == 99.0 and check_rate(1010.0) == 1010.0  # a clock's drift
    for bad in (50.0, 2000.0, float("nan")):
        with pytest.raises(InvalidInputError, match="valid rates are 100 Hz to 1000 Hz"):
            check_rate(bad, "the log")


def test_the_pipeline_runs_on_a_200_hz_csv(csvs, pipeline, capsys, tmp_path):
    assert pipeline["calibrate"] == 0 and pipeline["arm"].exists()
    assert pipeline["train"] == 0
    from iem.persistence import load_model

    model = load_model(pipeline["model"])
    assert (model.rate_hz, model.point_frames) == (100.0, 2)
    out = pipeline["printed"]
    assert "calibration.csv at 200 Hz (detected), block points of 2 frames: 100 per s" in out
    assert "joint states at 200 Hz (given), block points of 2 frames: 100 per s" in out

    summary = tmp_path / "replay.json"
    assert main(["replay", str(csvs["loaded"]), "--model", str(pipeline["model"]),
                 "--truth", str(REPO / "sim" / "payloads" / "test-3w.toml"), "--json",
                 str(summary),
                 "--no-status"]) == 0
    s = json.loads(summary.read_text())
    assert "recording at 200 Hz (detected), block points of 2 frames: 100 per s" in \
        capsys.readouterr().err
    assert (s["rate_hz"], s["rate_source"], s["block_frames"]) == (200.0, "detected", 2)
    assert s["frames"]["lost"] == 0  # the 5 ms steps are the recording's rate, not losses
    assert s["estimates"] == pytest.approx(600, abs=2)  # 100 block points a second, 6 s
    assert s["mae_groups"]["mass"] < 0.02  # measured 0.006 kg

    for reference in (["--bare", str(csvs["bare"])], ["--arm", str(pipeline["arm"])]):
        found = tmp_path / "found.json"
        assert main(["identify", "--loaded", str(csvs["loaded"]), *reference, "--out",
                     str(tmp_path / "found.toml"), "--json", str(found)]) == 0
        assert "loaded recording at 200 Hz (detected), equations every 2 samples: 100 per " \
               "s" in capsys.readouterr().out
        p, std = json.loads(found.read_text())["payload"], json.loads(found.read_text())["std"]
        assert abs(p["mass"] - TRUTH.mass) < max(3 * std["mass"], 0.003), reference
        np.testing.assert_allclose(p["com"], TRUTH.com, atol=0.002)


def test_a_given_rate_overrides_the_detected_one(csvs, pipeline, capsys, tmp_path):
    summary = tmp_path / "replay.json"
    assert main(["replay", str(csvs["loaded"]), "--model", str(pipeline["model"]),
                 "--rate", "400", "--json", str(summary), "--no-status"]) == 0
    s = json.loads(summary.read_text())
    assert (s["rate_hz"], s["rate_source"], s["block_frames"]) == (400.0, "given", 4)
    assert "recording at 400 Hz (given), block points of 4 frames" in capsys.readouterr().err
    from deploy.commands.calibrate import traffic_rate
    from deploy.commands.identify import recording_rate_line
    from iem.signals.recording import Recording

    t = np.arange(100) / 200.0
    part = (t, *(np.zeros((100, 7)) for _ in range(3)))
    assert traffic_rate([part], ["a"], None, log=lambda *a: None) == 200.0
    assert traffic_rate([part], ["a"], 250.0, log=lambda *a: None) == 250.0
    assert "at 500 Hz (given), equations every 5 samples" in recording_rate_line(
        Recording(*part), 500.0, "loaded")


def test_a_model_for_another_point_rate_is_refused_naming_the_train(csvs, pipeline, capsys):
    assert main(["replay", str(csvs["loaded"]), "--model", str(pipeline["model"]),
                 "--block-frames", "1", "--no-status"]) == 2
    err = capsys.readouterr().err
    assert "iem: error: the model was made for 100 block points per second" in err
    assert "is at 200 Hz, in blocks of 1 frames: 200" in err
    assert "'iem train --rate 200 --block-frames 1 --out MODEL'" in err


def test_recordings_at_different_rates_are_not_calibrated_together(tmp_path):
    from deploy.commands.calibrate import traffic_rate

    parts = [(np.arange(100) / r, *(np.zeros((100, 7)) for _ in range(3))) for r in (200, 1000)]
    with pytest.raises(InvalidInputError, match=r"different rates \(a at 200 Hz, b at 1000 Hz"):
        traffic_rate(parts, ["a", "b"], log=lambda *a: None)


@pytest.mark.parametrize("rate", [50.0, 2000.0])
def test_a_rate_outside_100_hz_to_1_khz_is_a_clear_error(rate, tmp_path, capsys):
    n = 400
    t = np.arange(n) / rate
    q = np.tile(np.linspace(0.0, 0.1, n)[:, None], (1, 7))
    csv = write_csv(tmp_path / "odd.csv", t, q, np.zeros((n, 7)), np.zeros((n, 7)))
    valid = "valid rates are 100 Hz to 1000 Hz"
    for argv in (["replay", str(csv), "--no-status"],
                 ["calibrate", str(csv), "--out", str(tmp_path / "arm.msgpack")],
                 ["identify", "--loaded", str(csv), "--bare", str(csv), "--out",
                  str(tmp_path / "p.toml")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "iem: error: " in err and f"at {rate:g} Hz: {valid}" in err, (argv, err)
    with pytest.raises(SystemExit) as info:
        main(["replay", str(csv), "--rate", f"{rate:g}"])
    assert info.value.code == 2 and valid in capsys.readouterr().err
