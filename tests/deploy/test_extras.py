"""A cell PC installs the core only: ``iem run``, ``calibrate`` and ``identify`` import and
run without the ``sim`` (MuJoCo) and ``plots`` (matplotlib) extras, and the commands that need
them stop with ``iem: error:`` naming the ``pip install`` (exit 2).

The extras are made unimportable in a child process by a meta-path finder that raises
ModuleNotFoundError for them, as an interpreter without them would; the child runs the
commands in-process and reports what each returned and printed.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from iem.errors import IemError, MissingExtraError
from iem.extras import EXTRAS, missing_extra, require
from tests.firmware_bridge.hil import REPO

CHILD = r'''
import contextlib, io, json, sys

BLOCKED = ("mujoco", "matplotlib")


class Absent:
    """Finds nothing of the blocked packages: ``import mujoco`` fails as if not installed."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, Absent())
out = {}
import deploy.service, deploy.commands.calibrate, deploy.commands.identify  # a cell PC's
from deploy.cli import main


def run(key, argv):
    err, std = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        try:
            rc = main(argv)
        except SystemExit as exc:  # argparse's --help
            rc = exc.code
    out[key] = {"rc": rc, "err": err.getvalue(), "out": std.getvalue()}


tmp = sys.argv[1]
for command in ("run", "calibrate", "identify"):
    run(f"{command} --help", [command, "--help"])
run("calibrate --write-motion", ["calibrate", "--write-motion", f"{tmp}/motion.csv"])

# iem identify on a loaded and a bare joint-state CSV computed with Pinocchio
import numpy as np
from sim.family import default_test_payload
from sim.paths import excitation_path
from sim.robot import ArmModel
from tests.firmware_bridge.test_recordings import write_csv

path, model = excitation_path(6.0, seed=0, period=3.0), ArmModel()
payload = default_test_payload()
t = np.arange(len(path)) * 1e-3
rng = np.random.default_rng(0)
for name, torque in (("loaded", lambda k: model.rnea_with_payload(
        path.q[k], path.dq[k], path.ddq[k], payload.to_phi())),
                     ("bare", lambda k: model.rnea(path.q[k], path.dq[k], path.ddq[k]))):
    tau = np.array([torque(k) for k in range(len(path))])
    write_csv(f"{tmp}/{name}.csv", t, path.q, path.dq, tau + rng.normal(0.0, 0.05, tau.shape))
run("identify", ["identify", "--loaded", f"{tmp}/loaded.csv", "--bare", f"{tmp}/bare.csv",
                 "--out", f"{tmp}/tool.toml"])
out["truth_mass"] = payload.mass

run("demo", ["demo", "--out", f"{tmp}/demo", "--no-status"])
run("sim-controller", ["sim-controller", "--interface", "serial-pty"])
run("bench sim", ["bench", "sim"])
out["imported"] = sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED)
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def without_extras(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("no-extras")
    done = subprocess.run([sys.executable, "-c", CHILD, str(tmp)], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1]), tmp


def test_the_cell_commands_run_without_the_sim_and_plots_extras(without_extras):
    res, tmp = without_extras
    assert res["imported"] == []
    for command in ("run", "calibrate", "identify"):
        assert res[f"{command} --help"]["rc"] == 0, res[f"{command} --help"]["err"]
        assert f"usage: iem {command}" in res[f"{command} --help"]["out"]
    assert res["calibrate --write-motion"]["rc"] == 0, res["calibrate --write-motion"]["err"]
    from sim.paths import calibration_path, load_path_csv

    written, motion = load_path_csv(tmp / "motion.csv"), calibration_path()
    assert written.duration == motion.duration
    np.testing.assert_allclose(written.q, motion.q, rtol=0, atol=1e-12)  # the motion, as CSV
    assert res["identify"]["rc"] == 0, res["identify"]["err"]
    from sim.payload import load_payload

    assert load_payload(tmp / "tool.toml").mass == pytest.approx(res["truth_mass"], abs=0.01)


@pytest.mark.parametrize(("command", "extra"), [
    ("demo", "sim"), ("sim-controller", "sim"), ("bench sim", "sim")])
def test_commands_that_simulate_name_the_extra_to_install(without_extras, command, extra):
    res, tmp = without_extras
    r = res[command]
    assert r["rc"] == 2
    assert r["err"].startswith("iem: error: ")
    assert f"pip install 'iem-payload[{extra}]'" in r["err"]
    assert "Traceback" not in r["err"]
    if command == "demo":
        assert not (tmp / "demo" / "summary.json").exists()  # stopped before simulating


def test_require_and_missing_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # what an absent package does
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)  # (loaded by an earlier test)
    with pytest.raises(MissingExtraError, match=r"the figures needs matplotlib \(the 'plots' "
                                                r"extra\).*pip install 'iem-payload\[plots\]'"):
        require("matplotlib.pyplot", "the figures")
    assert issubclass(MissingExtraError, IemError) and issubclass(MissingExtraError, ImportError)
    assert require("mujoco", "x").__name__ == "mujoco"  # (no re-import of matplotlib here:
    # a second copy of a package beside the first one's submodules breaks later imports)
    with pytest.raises(KeyError, match="not the module of an extra"):
        require("numpy", "x")
    error = missing_extra(ModuleNotFoundError("No module named 'mujoco'", name="mujoco"),
                          "iem demo")
    assert isinstance(error, MissingExtraError) and "iem-payload[sim]" in str(error)
    assert missing_extra(ModuleNotFoundError("No module named 'foo'", name="foo")) is None
    assert set(EXTRAS.values()) == {"sim", "plots", "ros2", "franka"}


def test_the_extras_are_declared_in_pyproject():
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert set(EXTRAS.values()) <= set(extras)
    core = " ".join(project["dependencies"])
    for module, extra in EXTRAS.items():
        assert module not in core, f"{module} is core; it belongs to the extra {extra!r}"
    assert "'.[dev,ros2,sim,plots,franka,franky]'" in (REPO / "Makefile").read_text()  # franka: the
    # real binding the franka link's fake is checked against (test_pylibfranka_binding.py)
