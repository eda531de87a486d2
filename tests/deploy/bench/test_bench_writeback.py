"""``iem bench writeback``: its measures on hand-made records, and the bookkeeping of a short
run against the simulated controller."""

from __future__ import annotations

import math

import numpy as np
import pytest

from deploy.bench.writeback import score
from deploy.bench.writeback.command import _scenarios, _seeds, figures_of, table, targets_of
from deploy.bench.writeback.real import score_case
from iem.errors import InvalidInputError
from iem.payload import Payload

TOOL = Payload("tool", 1.6, (0.0, 0.01, 0.06), (1e-3, 0.0, 0.0, 1e-3, 0.0, 1e-3))
OTHER = Payload("other", 1.3, (0.0, 0.0, 0.07), (1e-3, 0.0, 0.0, 1e-3, 0.0, 1e-3))


def applied(t, mass, com=(0.0, 0.0, 0.0)):
    return {"t": t, "seq": 1, "mass": mass, "com": list(com)}


def test_correct_is_within_50_g_and_10_mm():
    assert score.correct({"mass": 1.64, "com": [0.0, 0.01, 0.069]}, TOOL)
    assert not score.correct({"mass": 1.66, "com": [0.0, 0.01, 0.06]}, TOOL)
    assert not score.correct({"mass": 1.6, "com": [0.0, 0.01, 0.0711]}, TOOL)
    assert score.correct(None, None) and score.correct({"mass": 0.04, "com": [0, 0, 0]}, None)
    assert not score.correct(None, TOOL)
    # the empty load has no CoM: only the mass counts against it
    assert score.load_error(None, TOOL) == (pytest.approx(1.6), None)


def test_time_to_correct_of_a_removal():
    schedule = [(0.0, TOOL), (10.0, None)]
    record = [applied(3.0, 1.6, TOOL.com), applied(11.5, 0.0)]
    assert score.time_to_correct(None, record, schedule, 10.0, 20.0) == pytest.approx(1.5)
    # before the change the tool was correct from its write at 3 s on
    assert score.time_to_correct(None, record, schedule, 0.0, 9.0) == pytest.approx(3.0)
    # never cleared: not correct at the end
    assert score.time_to_correct(None, record[:1], schedule, 10.0, 20.0) is None
    # already correct at the change: 0
    assert score.time_to_correct(OTHER, [], [(0.0, OTHER)], 5.0, 9.0) == 0.0


def test_time_to_correct_counts_from_the_last_time_it_became_correct():
    schedule = [(0.0, TOOL)]
    record = [applied(1.0, 1.6, TOOL.com), applied(2.0, 1.0, TOOL.com),
              applied(4.0, 1.61, TOOL.com)]
    assert score.time_to_correct(None, record, schedule, 0.0, 6.0) == pytest.approx(4.0)


def test_a_write_that_errs_more_is_farther():
    schedule = [(0.0, TOOL)]
    record = [applied(1.0, 1.5, TOOL.com), applied(2.0, 1.6, TOOL.com),
              applied(3.0, 1.6, (0.0, 0.01, 0.09)), applied(4.0, 1.6, (0.0, 0.01, 0.0605))]
    rows = score.writes(None, record, schedule)
    assert [r["farther"] for r in rows] == [False, False, True, False]
    assert rows[0]["mass_error_kg"] == pytest.approx(0.1)
    assert rows[0]["before_mass_error_kg"] == pytest.approx(1.6)
    assert rows[2]["com_error_mm"] == pytest.approx(30.0)
    assert [r["correct"] for r in rows] == [False, True, False, True]
    assert score.worst(rows, "com_error_mm") == pytest.approx(30.0)


def test_in_band_uses_the_mass_and_first_moments():
    std = np.r_[0.01, 0.001, 0.001, 0.001, np.full(6, np.nan)]
    assert score.in_band({"mass": 1.615, "com": list(TOOL.com)}, TOOL, std)
    assert not score.in_band({"mass": 1.63, "com": list(TOOL.com)}, TOOL, std)
    assert score.in_band({"mass": 1.6, "com": [0, 0, 0]}, TOOL, np.full(10, np.nan)) is None


def test_reason_shares():
    shares = score.reason_shares([0, 1, 2, 3, 4], ["", "unstable", "unstable", "send", "x"],
                                 1, 3)
    assert shares == {"unstable": pytest.approx(2 / 3), "send": pytest.approx(1 / 3)}


def _run(**extra):
    run = {"scenario": "lost_1", "plant": "ideal", "seed": 0, "part": 0, "drops": 1,
           "initial_load": None, "schedule": [(0.0, score.load_of(TOOL))],
           "sends": [{"t": 2.0, "load": score.load_of(TOOL)},
                     {"t": 3.0, "load": score.load_of(TOOL)}],
           "controller": {"applied": [applied(3.01, 1.6, TOOL.com)], "load_in_force":
                          {"mass": 1.6, "com": list(TOOL.com)}, "refused_moving": 0},
           "summary": {"writes": {"sent": 2, "acked": 1, "lost": 1, "in_force": 1},
                       "gate": {"send": 2}},
           "t": np.arange(0.0, 6.0, 0.01), "reasons": ["no_change"] * 600,
           "end_s": 6.0, "gate_in_force": score.load_of(TOOL), "log": []}
    run.update(extra)
    return run


def test_lost_target_counts_from_the_first_command_and_needs_the_loss_counted():
    t = targets_of(_run())
    assert t["met"] and t["time_to_correct_s"] == pytest.approx(1.01)
    miscounted = _run(summary={"writes": {"sent": 2, "acked": 2, "lost": 0, "in_force": 2},
                               "gate": {}})
    assert not targets_of(miscounted)["met"]
    late = _run(controller={"applied": [applied(12.5, 1.6, TOOL.com)], "load_in_force": None,
                            "refused_moving": 0}, end_s=13.0)
    missed = targets_of(late)
    assert not missed["met"] and "no_change" in missed["why"]


def test_restart_target_refuses_a_write_of_the_old_payload():
    old = score.load_of(OTHER)
    base = dict(scenario="restart", part=1, old=old, schedule=[(0.0, score.load_of(TOOL))],
                initial_load=old)
    assert targets_of(_run(**base))["met"]
    again = _run(**base, sends=[{"t": 1.0, "load": old}])
    assert not targets_of(again)["met"]
    assert targets_of(_run(scenario="restart", part=0)) is None


def test_figures_and_table_of_a_run():
    f = figures_of(_run())
    assert f["farther"] == 0 and len(f["writes"]) == 1
    text = table({"runs": [f], "real": None})
    assert "lost_1" in text and "MET" in text and "simulation only" in text


def test_real_case_scoring():
    t = np.arange(5.0, 15.0, 0.01)
    std = np.tile(np.r_[0.02, 0.002, 0.002, 0.002, np.full(6, 0.01)], (t.size, 1))
    good = [{"t": 8.0, "mass": 1.62, "com": list(TOOL.com)}]
    c = score_case("tool", TOOL, t, std, good)
    assert c["met"] and c["first_write_s"] == pytest.approx(3.0)
    late = score_case("tool", TOOL, t, std, [{**good[0], "t": 15.5}])
    assert not late["met"]
    assert score_case("bare", None, t, std, [])["met"]
    assert not score_case("bare", None, t, std, good)["met"]
    assert score_case("tool", TOOL, t, std, [])["first_write_s"] is None


def test_bad_options_name_what_is_valid():
    assert _seeds("0, 2") == [0, 2]
    for bad in ("", "a", "-1"):
        with pytest.raises(InvalidInputError, match="valid is"):
            _seeds(bad)
    with pytest.raises(InvalidInputError, match="valid are"):
        _scenarios("tool_removed,nope")


def test_cli_refuses_bad_seeds(capsys):
    from deploy.cli import main

    assert main(["bench", "writeback", "--seeds", "x"]) == 2
    assert "iem: error: --seeds" in capsys.readouterr().err


def test_short_run_bookkeeping(trained_phys_model_file):
    """A short tool removal on the ideal plant: the record agrees with itself and with the
    controller's own."""
    pytest.importorskip("mujoco")
    from deploy.bench.writeback.scenarios import Plant, Timing, run_scenario
    from iem.persistence import load_model

    plant = Plant("ideal", 0, load_model(trained_phys_model_file))
    runs = run_scenario("tool_removed", plant, Timing(2.0, 1.5, 3.0, 3.0, 2.0, 1.0),
                        log=lambda *a: None)
    assert len(runs) == 1
    run = runs[0]
    assert run["change_s"] == 2.0 and 3.4 <= run["end_s"] <= 3.7
    c = run["controller"]
    assert [m["payload"] for m in c["mounted"]] == ["test-3w", None]
    assert c["mounted"][1]["t"] == pytest.approx(2.0)
    assert np.all(np.diff(run["t"]) > 0) and run["t"][-1] <= run["end_s"]
    assert run["smoothed"].shape == run["std"].shape == (run["t"].size, 10)
    w = run["summary"]["writes"]
    assert w["sent"] == len(run["sends"]) and len(c["applied"]) == w["in_force"]
    assert all(0.0 <= s["t"] <= run["end_s"] for s in run["sends"])
    f = figures_of(run)
    assert f["target"]["met"] in (True, False)
    assert math.isfinite(f["end_s"])


@pytest.mark.smoke
def test_a_figure_per_run(tmp_path):
    pytest.importorskip("matplotlib")
    from deploy.bench.writeback.figures import write_figures

    run = _run()
    n = run["t"].size
    run["smoothed"] = np.tile(TOOL.to_phi(), (n, 1))
    run["std"] = np.full((n, 10), 0.01)
    names = write_figures(tmp_path, [run, _run(scenario="restart", part=1, smoothed=
                                               run["smoothed"], std=run["std"])], None)
    assert names == ["lost_1-ideal-seed0.png", "restart-ideal-seed0-part1.png"]
    assert all((tmp_path / n).stat().st_size > 1000 for n in names)
