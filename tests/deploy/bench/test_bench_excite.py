"""``iem bench excite``: the designed motion's figures and, per seed, what identify and the
live estimate make of it on the realistic plant (a short run: one seed, a 4 s motion)."""

import json

import pytest

from deploy.cli import main

pytest.importorskip("mujoco")


@pytest.mark.slow
def test_bench_excite_prints_the_design_and_every_payloads_figures(tmp_path, capsys):
    out = tmp_path / "excite.json"
    assert main(["bench", "excite", "--seeds", "0", "--seconds", "4", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "condition" in printed and "excitation path" in printed
    r = json.loads(out.read_text())
    assert r["design"]["condition"] < r["design"]["condition_of"]["excitation"]
    assert max(r["design"]["dq_peak_share"]) <= 0.75 + 1e-9
    rows = r["seeds"]["0"]
    assert set(rows) == {"test-3w", "light-tool", "offaxis-tool"}
    for row in rows.values():
        assert set(row) == {"identify+bare", "identify+arm", "live"}
        mass, com = row["identify+bare"]
        assert abs(mass) < 0.05 and com < 5.0  # the bare run cancels the arm's error
    assert set(r["met"]) == {"identify+bare", "identify+arm", "live"}
