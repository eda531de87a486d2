"""Exit statuses and messages of ``iem`` on bad input: a configuration error ends in one line
``iem: error: ...`` (in ``iem run``'s JSON logging, its ``fatal`` record) naming the file or
key and what is valid, with status 78 (EX_CONFIG), so systemd does not restart into it; a
link failure keeps status 2 (restarted)."""

from __future__ import annotations

import configparser
from pathlib import Path

import pytest

from deploy.cli import EX_CONFIG, main

from .conftest import cell_config, fatal_line, write_toml

UNIT = Path(__file__).resolve().parents[2] / "deploy" / "iem.service"


@pytest.fixture(autouse=True)
def restore_iem_logger():
    """``iem run`` points the ``iem`` loggers at this test's stderr; put them back."""
    import logging

    root = logging.getLogger("iem")
    saved = root.handlers[:], root.level, root.propagate
    yield
    root.handlers[:], root.level, root.propagate = saved


def run_iem(capsys, *argv: str) -> tuple[int, str]:
    status = main(list(argv))
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err


def test_the_config_status_is_sysexits_ex_config_and_the_unit_does_not_restart_on_it():
    assert EX_CONFIG == 78
    unit = configparser.ConfigParser(interpolation=None, strict=True)
    unit.optionxform = str
    unit.read_string(UNIT.read_text())
    assert unit["Service"]["RestartPreventExitStatus"].split() == ["78"]
    assert unit["Service"]["Restart"] == "on-failure"  # link failures (2) still restart


def test_a_non_utf8_cell_toml(tmp_path, capsys):
    path = tmp_path / "cell.toml"
    path.write_bytes(b'[link]\nchannel = "can\xff0"\n')
    status, err = run_iem(capsys, "run", "--config", str(path))
    assert status == EX_CONFIG
    assert err.startswith(f"iem: error: {path}: not UTF-8 text (byte 0xff on line 2, offset 21)")
    assert "must be UTF-8" in err and err.count("\n") == 1


def test_a_non_utf8_payload_file(tmp_path, capsys):
    payload = tmp_path / "payload.toml"
    payload.write_bytes(b'name = "b\xe9cher"\nmass = 1.0\n')  # Latin-1, not UTF-8
    status, err = run_iem(capsys, "replay", str(tmp_path / "traffic.blf"), "--truth",
                          str(payload))
    assert status == 2  # a command at a terminal: only the service exits EX_CONFIG
    assert err.startswith(f"iem: error: {payload}: not UTF-8 text (byte 0xe9 on line 1, "
                          "offset 9); a payload file must be UTF-8")


@pytest.mark.parametrize(("seed", "parts"), [
    ("-1", ["[model] seed = -1 is out of range", "valid is an integer from 0 to "]),
    ("1.5", ["[model] seed = 1.5 must be an integer from 0 to "]),
])
def test_a_seed_out_of_range(tmp_path, capsys, seed, parts):
    path = tmp_path / "cell.toml"
    path.write_text(f"[model]\nseed = {seed}\n")
    status, err = run_iem(capsys, "run", "--config", str(path))
    assert status == EX_CONFIG and err.startswith(f"iem: error: {path}: ")
    for part in parts:
        assert part in err


@pytest.mark.parametrize(("text", "part"), [
    ("[gate]\nmax_nis = 0.5\n", "[gate] max_nis = 0.5 is out of range; valid is [1, 1e+06]"),
    ("[gate]\nmax_mass_2sigma_kg = 0.02\n",
     "[gate] max_mass_2sigma_kg: not a setting of this gate"),
    ("[gate]\nwrite_margin = 0\n", "[gate] write_margin = 0.0 is out of range"),
    ("[gate]\nrefusal_retry_s = 5.0\nrefusal_retry_max_s = 2.0\n",
     "refusal_retry_max_s = 2.0 is below refusal_retry_s = 5.0; valid is refusal_retry_max_s"),
    ("[gate]\nmax_nsi = 3\n", "unknown key(s) ['max_nsi'] in [gate]"),
    ("[gate]\nrated_mass_kg = 50.0\n",
     "[gate] rated_mass_kg = 50 is above the rated payload of [arm] model = 'panda', 3 kg"),
    ("[gate]\nempty_mass_kg = 0.2\n", "[gate] empty_mass_kg: not a setting of this gate"),
    ("[link]\nkind = socketcan\n", "not valid TOML"),
])
def test_bad_keys_and_values_are_config_errors(tmp_path, capsys, text, part):
    path = tmp_path / "cell.toml"
    path.write_text(text)
    status, err = run_iem(capsys, "run", "--config", str(path))
    assert status == EX_CONFIG and part in err, err


def test_a_missing_cell_toml_is_a_config_error(tmp_path, capsys):
    status, err = run_iem(capsys, "run", "--config", str(tmp_path / "nope.toml"))
    assert status == EX_CONFIG and "cannot read the configuration" in err


@pytest.mark.hil
def test_a_link_failure_keeps_status_2(tmp_path, capsys, model_file):
    """An slcan adapter that is not there: the link fails to open (systemd retries)."""
    doc = cell_config(model_file, {"kind": "slcan", "channel": str(tmp_path / "ttyACM9")})
    status, err = run_iem(capsys, "run", "--config", str(write_toml(tmp_path / "cell.toml",
                                                                    doc)))
    assert status == 2
    last = fatal_line(err)  # after the JSON logs of the start, as one of them
    assert last.startswith("iem: error: cannot open slcan bus") and "ttyACM9" in last


def test_a_bad_path_file_is_a_config_error(tmp_path, capsys):
    path = tmp_path / "path.csv"
    path.write_bytes(b"t,q1,q2,q3,q4,q5,q6,q7\n0,\xff\n")
    status, err = run_iem(capsys, "sim-controller", "--interface", "virtual", "--path",
                          str(path))
    assert status == 2 and err.startswith(f"iem: error: {path}: not UTF-8 text")
    assert "a path file must be UTF-8" in err


def test_which_errors_are_configuration_errors():
    from deploy.cli import EX_ERROR, exit_status
    from deploy.config import ConfigError
    from firmware_bridge.errors import (
        BridgeConfigError,
        EncodeError,
        LinkError,
        LogFileError,
    )
    from iem.errors import ModelFileError, PathError, PayloadError

    for exc in (ConfigError("x"), PayloadError("x"), PathError("x"), BridgeConfigError("x")):
        assert exit_status(exc) == EX_CONFIG, exc
        assert exit_status(exc, "replay") == exit_status(exc, "train") == EX_ERROR, exc
    # a restart may help (the adapter is back), or it is a data file, not the configuration
    for exc in (LinkError("x"), ModelFileError("x"), LogFileError("x"), EncodeError("x")):
        assert exit_status(exc) == EX_ERROR == 2, exc


# -- every file cell.toml names: missing or unreadable exits 78 ------------------------------
def _fifo(path: Path) -> Path:
    import os

    os.mkfifo(path)
    return path


FILE_KEYS = {
    # key: (what to set, how the named file is made, what the message names)
    "[model] path, missing": (lambda t, m: {"model": {"path": str(t / "none.msgpack")}},
                              None, "[model] path = "),
    "[model] path, not a model": (lambda t, m: {"model": {"path": str(t / "junk.msgpack")}},
                                  lambda t: (t / "junk.msgpack").write_bytes(b"not a model"),
                                  "is not a msgpack model file"),
    "[model] path, a FIFO": (lambda t, m: {"model": {"path": str(t / "pipe.msgpack")}},
                             lambda t: _fifo(t / "pipe.msgpack"), "it is a FIFO"),
    "[model] arm, missing": (lambda t, m: {"model": {"arm": str(t / "none-arm.msgpack")}},
                             None, "[model] arm = "),
    "[model] arm, a FIFO": (lambda t, m: {"model": {"arm": str(t / "arm-pipe")}},
                            lambda t: _fifo(t / "arm-pipe"), "it is a FIFO"),
    "[model] excitation, missing": (lambda t, m: {"model": {
        "path": str(t / "new.msgpack"), "train_if_missing": True,
        "excitation": str(t / "none.csv")}}, None, "none.csv"),
    "[arm] model, missing": (lambda t, m: {"arm": {"model": str(t / "none.urdf")},
                                           "gate": {"rated_mass_kg": 3.0}}, None,
                             "none.urdf: cannot read the URDF file: it does not exist"),
    "[arm] end_effector, missing": (lambda t, m: {"arm": {"end_effector": str(t / "no.toml")}},
                                    None, "cannot read the payload file: it does not exist"),
    "[arm] end_effector, a FIFO": (lambda t, m: {"arm": {"end_effector": str(t / "ee.toml")}},
                                   lambda t: _fifo(t / "ee.toml"), "it is a FIFO"),
    "[estimate] initial_payload, missing": (
        lambda t, m: {"estimate": {"initial_payload": str(t / "no.toml")}}, None,
        "cannot read the payload file: it does not exist"),
    "[link] channel of a replay, missing": (
        lambda t, m: {"link": {"kind": "replay", "channel": str(t / "none.blf")}}, None,
        "[link] channel = "),
    "[link] channel of a recording, a FIFO": (
        lambda t, m: {"link": {"kind": "recording", "channel": str(t / "pipe.csv")}},
        lambda t: _fifo(t / "pipe.csv"), "it is a FIFO"),
}


@pytest.mark.parametrize("case", sorted(FILE_KEYS))
def test_every_file_cell_toml_names_exits_78_when_missing_or_unreadable(tmp_path, capsys,
                                                                        phys_model_file,
                                                                        case):
    """Whatever its key, a file the configuration names that cannot be read is the
    configuration's error: exit 78 (systemd does not restart into it), one line naming it.
    A missing [model] arm exited 2 (five restarts), a missing initial_payload 78."""
    from tests.watchdog import within

    sections, make, named = FILE_KEYS[case]
    if make is not None:
        make(tmp_path)
    sections = sections(tmp_path, phys_model_file)
    link = sections.pop("link", {"kind": "virtual", "channel": f"exit-{case}"})
    doc = cell_config(phys_model_file, link, **sections)
    with within(60):
        status, err = run_iem(capsys, "run", "--config",
                              str(write_toml(tmp_path / "cell.toml", doc)))
    last = fatal_line(err)
    assert status == EX_CONFIG, (case, err)
    assert last.startswith("iem: error: ") and named in last, (case, last)


@pytest.mark.parametrize("command", [["run", "--config", "cell.toml"],
                                     ["sim-controller", "--interface", "virtual"]])
@pytest.mark.parametrize("duration", ["nan", "-5", "0", "inf", "soon"])
def test_a_duration_that_is_not_a_number_of_seconds_is_a_usage_error(capsys, command,
                                                                     duration):
    """``iem run --duration nan`` ran for ever and ``--duration -5`` exited 0 at once: a
    duration is a finite number of seconds > 0, or the command does not start."""
    with pytest.raises(SystemExit) as exit_:
        main([*command, "--duration", duration])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f"argument --duration: {duration!r}: valid is a number of seconds > 0" in err
