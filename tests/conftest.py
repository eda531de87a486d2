"""Every test leaves the ``iem`` logger as it found it: a command run in a test
(``deploy.cli.main``) routes it to that test's captured stderr and stops its propagation,
which would otherwise write later tests' logs to a closed stream and hide them from caplog.

The lightly trained models, saved once per session for every folder of tests that needs
one (a test that changes its model loads its own copy; tests/deploy/conftest.py gives each
test a private copy of the file), and the bare arm's calibration run with the arm file
``iem calibrate`` writes from it as a CAN log, which tests/sim/test_calibration.py checks and
tests/deploy/test_arm.py trains for."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _restore_iem_logger():
    logger = logging.getLogger("iem")
    saved = (list(logger.handlers), logger.level, logger.propagate)
    yield
    logger.handlers[:], logger.level, logger.propagate = saved


def _trained_file(kind: str, tmp_path_factory, arm_model: str | None = None) -> Path:
    """A model of ``kind`` trained on the excitation path (lightly, to keep tests quick) for
    the arm model ``arm_model`` (None: the default), saved once per session."""
    from deploy.model.training import train_initial_model
    from iem.persistence import save_model

    model = train_initial_model(kind, seed=0, log=lambda *a: None, fit_epochs=3, fit_stride=20,
                                noise="sensor",  # the simulated arm is its model
                                description=arm_model)
    path = tmp_path_factory.mktemp("model") / "trained.msgpack"
    save_model(model, path)
    return path


@pytest.fixture(scope="session")
def trained_model_file(tmp_path_factory) -> Path:
    """The paper's IEM."""
    return _trained_file("IEM", tmp_path_factory)


@pytest.fixture(scope="session")
def trained_phys_model_file(tmp_path_factory) -> Path:
    """The deployed kind, IEM+phys: its estimates are projected onto physically consistent
    parameters, so the gate's decisions over a real-time run do not hang on whether the
    paper's IEM happened to give a consistent inertia at an instant."""
    return _trained_file("IEM+phys", tmp_path_factory)


@pytest.fixture(scope="session")
def trained_fr3_phys_model_file(tmp_path_factory) -> Path:
    """IEM+phys for the FR3 (the franka link's arm)."""
    return _trained_file("IEM+phys", tmp_path_factory, "fr3")


@pytest.fixture(scope="session")
def trained_fr3_model_file(tmp_path_factory) -> Path:
    """The paper's IEM for the FR3 (no uncertainty: a gate that allows it writes once the
    estimate is stable, whatever the arm's friction does to it)."""
    return _trained_file("IEM", tmp_path_factory, "fr3")


# -- an arm calibrated from a CAN log ------------------------------------------------------------
@pytest.fixture(scope="session")
def bare_calibration_run():
    """``(plant, rollout)``: the calibration motion on the modelled-only plant of gap seed 3
    (links, friction and offsets: all the arm model describes, so that what a calibration
    recovers can be checked against ``plant.arm``), noise seed 101. Its arrays are
    read-only: every module that calibrates from it sees the same run."""
    from sim.paths import calibration_path
    from sim.plant import ArmPlant, RealityGap

    plant = ArmPlant(gap=RealityGap(seed=3).modelled_only(), seed=101)
    rollout = plant.follow(calibration_path())
    for a in vars(rollout).values():
        a.flags.writeable = False
    return plant, rollout


@pytest.fixture(scope="session")
def calibrated_from_a_can_log(bare_calibration_run, tmp_path_factory) -> dict:
    """``iem calibrate`` on that run written as a CAN log (``tests.can_logs.write_log``): its
    exit status, what it printed, the log and the arm file it wrote."""
    import contextlib
    import io

    from deploy.cli import main
    from tests.can_logs import write_log

    d = tmp_path_factory.mktemp("calibrated")
    log_file, arm_file = d / "bare.blf", d / "arm.msgpack"
    write_log(bare_calibration_run[1], log_file)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        status = main(["calibrate", str(log_file), "--out", str(arm_file)])
    return {"status": status, "printed": printed.getvalue(), "log": log_file, "arm": arm_file}
