"""The ``iem`` command's dispatch table and its error handling."""

import json
import subprocess
import sys

import pytest

from deploy.cli import COMMANDS, main


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


def test_unknown_command_names_the_valid_ones(capsys):
    assert main(["nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'nope'" in err and "demo" in err


def test_nested_group_help(capsys):
    assert main(["bench"]) == 2
    assert "sim" in capsys.readouterr().out


@pytest.mark.smoke
def test_bench_sim_writes_json(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, "-m", "deploy.cli", "bench", "sim", "--calls", "50",
                           "--json", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(out.read_text())
    for key in ("rnea_us", "regressor_us", "tandem_us_per_point", "plant_realtime_factor"):
        assert figures[key] > 0
    assert "tandem" in proc.stdout
