"""``iem bench fci``'s scores from a truth log alone (:mod:`deploy.bench.fci.score`), its
figure, its schedule, and its command line's refusals; the bench itself runs franky-sim for
minutes (``pytest -m slow``)."""

from __future__ import annotations

import numpy as np
import pytest

from deploy.bench.fci.schedule import PAYLOADS, payload_files, steps
from deploy.bench.fci.score import arrivals_ms, changes, cost_us, timelines
from deploy.cli import main
from sim.payload import load_payload

PAYLOAD = {"name": "test-3w", "mass": 1.615, "com": [-0.006, 0.006, 0.064],
           "inertia": [0.0043, -0.0004, -0.0008, 0.0043, 0.0, 0.0046]}
Q = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]


def written(mass, com):
    return [mass, com, [0.0043, -0.0004, -0.0008, -0.0004, 0.0043, 0.0, -0.0008, 0.0, 0.0046]
            if mass else [0.0] * 9]


def log(*, clear_at=9.3, extra=()):
    """A run: mounted at 1, carried from 1.5 to 4.5 (a refusal at 2), written at 4.7,
    released at 5.5, bare from 6 to 9, cleared at ``clear_at``."""
    events = [(1.0, "mount", PAYLOAD), (1.5, "motion_start", "program"),
              (2.0, "refused", 1.6), (4.5, "motion_end", "program"),
              (4.7, "set_load", written(1.612, [-0.005, 0.006, 0.060])),
              (5.5, "unmount", None), (6.0, "motion_start", "program"),
              (9.0, "motion_end", "program")]
    events += [(t, "pose", Q) for t in np.arange(1.5, 4.5, 0.1)]
    events += [(t, "pose", Q) for t in np.arange(6.0, 9.0, 0.1)]
    if clear_at is not None:
        events.append((clear_at, "set_load", written(0.0, [0.0] * 3)))
    return sorted([*events, *extra], key=lambda e: e[0])


def regressor(q):
    from sim.robot import ArmModel

    zero = np.zeros(7)
    return ArmModel(description="fr3").payload_regressor(np.asarray(q), zero, zero)


def test_each_change_is_timed_from_the_end_of_the_motion_that_carried_it():
    mount, release = changes(log(), regressor, 12.0)
    assert mount["latency_s"] == pytest.approx(0.2) and mount["correct"]
    assert mount["refusals"] == mount["refusals_moving"] == 1 and mount["farther"] == 0
    assert mount["mass_error_kg"] == pytest.approx(0.003) and mount["com_error_mm"] < 5.0
    assert release["latency_s"] == pytest.approx(0.3) and release["bare_writes"] == 0
    assert release["mass_error_kg"] == 0.0 and release["torque_error_nm"] == 0.0


def test_a_load_never_cleared_and_a_bare_write_are_counted():
    _, release = changes(log(clear_at=None, extra=[(9.2, "set_load", written(
        2.0, [0.0, 0.0, 0.05]))]), regressor, 12.0)
    assert release["latency_s"] is None and not release["correct"]
    assert release["bare_writes"] == 1 and release["farther"] == 1
    assert release["torque_error_nm"] > 1.0


def test_a_change_never_correct_says_what_the_gate_held_it_with():
    """The release is never cleared: from the end of its motion (9 s) to the run's end the
    client's record of the gate's reasons gives its shares, and the target's line names
    them; a change that was correct has none."""
    from deploy.bench.fci.command import targets

    times = np.arange(0.0, 12.0, 0.01)
    reasons = ["send" if t < 4.7 else "uncertain" if t < 10.5 else "no_change" for t in times]
    rows = [[t] + [0.0] * 8 for t in times]
    mount, release = changes(log(clear_at=None), regressor, 12.0, rows, reasons)
    assert mount["held"] is None
    assert release["held"] == pytest.approx({"uncertain": 0.5, "no_change": 0.5}, abs=0.01)
    result = {"changes": [mount, release], "callback_us": None}
    (met, line), *_ = [(m, text) for _, m, text in targets(result, 1.0)]
    assert not met and "0.000 kg: gate held: uncertain 50 %, no_change 50 %" in line


def test_a_light_payload_is_judged_by_the_torque_it_leaves():
    """Under 1 kg, a load within 0.1 N·m at the carrying motion's poses is correct, however
    far its CoM (what the poses cannot tell apart does not count)."""
    light = {**PAYLOAD, "mass": 0.6, "com": [0.03, -0.02, 0.05]}
    events = [(0.5, "mount", light), (1.0, "motion_start", "c"), (3.0, "motion_end", "c"),
              (3.1, "set_load", written(0.6, [0.03, -0.02, 0.062]))]  # 12 mm off in z
    events += [(t, "pose", Q) for t in np.arange(1.0, 3.0, 0.1)]  # the flange points down
    (row,) = changes(sorted(events, key=lambda e: e[0]), regressor, 5.0)
    assert row["com_error_mm"] > 10.0 and row["torque_error_nm"] < 0.1 and row["correct"]


def test_the_timelines_and_the_callback_cost():
    tl = timelines(log())
    assert [v and v["mass"] for _, v in tl["truth"]] == [None, 1.615, None]
    assert tl["motions"] == [(1.5, 4.5), (6.0, 9.0)] and tl["refused"] == [2.0]
    c = cost_us([1000] * 99 + [100000])
    assert c["n"] == 100 and c["p50"] == 1.0 and c["max"] == 100.0


def test_the_control_loops_pace_counts_late_callbacks_within_motions_only():
    """Two motions of 1 ms steps, one step held 3 ms, and 2 s of rest between them: the rest
    is no step; the held one is late."""
    ms = 1_000_000
    first = [k * ms for k in range(100)]
    first[60:] = [t + 2 * ms for t in first[60:]]  # the loop held 2 ms beyond its cycle
    second = [first[-1] + 2000 * ms + k * ms for k in range(100)]
    a = arrivals_ms(first + second)
    assert a["n"] == 198 and a["late"] == 1 and a["max"] == pytest.approx(3.0)
    assert a["p50"] == pytest.approx(1.0) and arrivals_ms([5]) is None


def test_the_figure_is_drawn(tmp_path):
    pytest.importorskip("matplotlib")
    from deploy.bench.fci.figures import write_figure

    rows = [[t, 1.6, 0.0, 0.0, 0.1, 0.05, 0.01, 0.01, 0.01] for t in np.arange(1.5, 5.0, 0.01)]
    name = write_figure(tmp_path / "fci.png", {"events": log(), "rows": rows, "end_s": 12.0},
                        "test")
    assert (tmp_path / name).stat().st_size > 10_000


def test_the_schedule_picks_and_places_each_payload():
    kinds = [s.kind for s in steps()]
    assert kinds.count("grasp") == kinds.count("release") == len(PAYLOADS)
    assert kinds.count("move") == 1 + 2 * len(PAYLOADS)
    masses = [load_payload(p).mass for p in payload_files()]
    assert min(masses) < 1.0 < max(masses) and max(masses) + 0.73 <= 3.0  # FR3: 3 kg rated


def test_bad_command_lines_are_refused(capsys):
    assert main(["bench", "fci", "--ways", "telepathy"]) == 2
    assert "valid are program, run" in capsys.readouterr().err
    assert main(["bench", "fci", "--arm", "a.msgpack"]) == 2
    assert "--arm and --model together" in capsys.readouterr().err
    assert main(["bench", "fci", "--payloads", "4"]) == 2
    assert "1 to 3" in capsys.readouterr().err
