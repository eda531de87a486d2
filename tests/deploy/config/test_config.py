"""``cell.toml``: the example documents every key; bad input names key, value and what is valid."""

import os
import re
import tomllib
from dataclasses import fields, replace
from pathlib import Path

import pytest

from deploy.config import (
    DERIVED_GATE_KEYS,
    INT_RANGES,
    RANGES,
    SECTIONS,
    CellConfig,
    ConfigError,
    LinkConfig,
    ModelConfig,
    config_from_dict,
    load_config,
)
from tests.watchdog import within

EXAMPLE = Path(__file__).resolve().parents[3] / "deploy" / "cell.toml"


def write(tmp_path, text: str, name: str = "cell.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# -- the example file -------------------------------------------------------------------------
def test_example_loads_with_cell_pc_values():
    cfg = load_config(EXAMPLE)
    assert (cfg.link.kind, cfg.link.channel, cfg.link.profile) == ("socketcan", "can0", "fd")
    assert cfg.model.path == "/var/lib/iem/model.msgpack"
    assert (cfg.log.format, cfg.log.status_line) == ("json", "auto")
    assert cfg.source == str(EXAMPLE)


def test_example_sets_and_documents_every_key():
    text = EXAMPLE.read_text()
    doc = tomllib.loads(text)
    assert set(doc) == set(SECTIONS)
    for section, cls in SECTIONS.items():
        names = {f.name for f in fields(cls)} - set(DERIVED_GATE_KEYS)
        assert set(doc[section]) == names, f"[{section}] keys differ from {cls.__name__}"
        start = text.index(f"\n[{section}]\n")
        end = text.find("\n[", start + 1)
        part = text[start:end if end > 0 else len(text)]
        for name in names:
            assert re.search(rf"^# {name}: \S", part, re.M), f"[{section}] {name} undocumented"
            # its comment states the default, and it is the dataclass's
            block = part[part.index(f"# {name}:"):part.index(f"\n{name} =")]
            stated = re.search(r"Default (\S+?)\.?(?:\s|$)", block)
            assert stated, f"[{section}] {name}: no default stated"
            assert_same(stated.group(1), getattr(cls(), name), f"[{section}] {name}")


CELL_PC_VALUES = {("link", "kind"), ("link", "channel"), ("model", "path")}
"""The keys the example sets to a cell PC's value instead of the default its comment states."""


def key_comments(text: str, section: str) -> dict[str, str]:
    """Each key of ``[section]`` -> its comment block, the '# ' markers removed."""
    start = text.index(f"\n[{section}]\n")
    end = text.find("\n[", start + 1)
    part = text[start:end if end > 0 else len(text)]
    out = {}
    for name in re.findall(r"^(\w+) = ", part, re.M):
        block = part[part.index(f"# {name}:"):part.index(f"\n{name} =")]
        out[name] = " ".join(line.removeprefix("#").strip() for line in block.splitlines())
    return out


def test_every_key_of_the_example_is_the_dataclass_default():
    """The dataclasses are the one source of the defaults: the example sets each key to its
    default, but for the few it sets to a cell PC's values (their comments state the
    default, checked above)."""
    doc = tomllib.loads(EXAMPLE.read_text())
    for section, cls in SECTIONS.items():
        defaults = cls()
        for name, value in doc[section].items():
            value = tuple(value) if isinstance(value, list) else value
            if (section, name) in CELL_PC_VALUES:
                assert value != getattr(defaults, name), f"[{section}] {name}"
            else:
                assert value == getattr(defaults, name), f"[{section}] {name} = {value!r}"
                assert type(value) is type(getattr(defaults, name)), f"[{section}] {name}"


def test_every_range_the_example_states_is_the_checked_one():
    """A numeric key's comment states the range ``config.py`` checks ("lo to hi"; an int key
    whose -1 means "none" states 0 to hi and the -1), and a key without one states none."""
    text = EXAMPLE.read_text()
    number = r"-?\d[\d.e+]*\d|\d"
    for section, cls in SECTIONS.items():
        comments = key_comments(text, section)
        for f in fields(cls):
            default = getattr(cls(), f.name)
            if type(default) not in (int, float) or f.name in DERIVED_GATE_KEYS:
                continue
            stated = {(float(lo), float(hi)) for lo, hi in
                      re.findall(rf"({number}) to ({number})", comments[f.name])}
            code = RANGES.get((section, f.name)) or INT_RANGES.get((section, f.name))
            what = f"[{section}] {f.name}: stated {stated}, checked {code}"
            if code is None:
                assert not stated, what
            elif code[0] == -1:
                assert (0.0, float(code[1])) in stated and "-1" in comments[f.name], what
            else:
                assert (float(code[0]), float(code[1])) in stated, what


def assert_same(token: str, default, what: str) -> None:
    if isinstance(default, bool):
        assert token == str(default).lower(), what
    elif isinstance(default, str):
        assert token == f'"{default}"', what
    elif isinstance(default, tuple):
        assert token == repr(list(default)), what
    else:
        assert float(token) == default, what


# -- defaults and paths ---------------------------------------------------------------------
def test_missing_keys_take_the_defaults():
    from sim.end_effector import end_effector

    cfg = config_from_dict({})
    hand = end_effector("franka_hand").mass  # [arm] end_effector's default, on the gate
    arm = replace(CellConfig().arm, model="panda", end_effector="franka_hand")  # the Panda's
    assert cfg == replace(CellConfig(source="config"), arm=arm,
                          gate=replace(CellConfig().gate, end_effector_mass_kg=hand))
    cfg = config_from_dict({"link": {"channel": "vcan0"}})
    assert cfg.link == LinkConfig(channel="vcan0")
    assert cfg.model == ModelConfig()


def test_an_int_is_accepted_for_a_float():
    cfg = config_from_dict({"link": {"silence_timeout_s": 1}})
    assert cfg.link.silence_timeout_s == 1.0 and isinstance(cfg.link.silence_timeout_s, float)


def test_relative_model_path_is_taken_from_the_config_folder(tmp_path):
    sub = tmp_path / "etc"
    sub.mkdir()
    cfg = load_config(write(sub, '[model]\npath = "models/m.msgpack"\n'))
    assert Path(cfg.model.path) == sub / "models" / "m.msgpack"
    assert Path(load_config(write(sub, "")).model.path) == sub / "model.msgpack"
    cfg = load_config(write(sub, '[model]\npath = "/var/lib/iem/x.msgpack"\n'))
    assert cfg.model.path == "/var/lib/iem/x.msgpack"


# -- errors ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "parts"), [
    ("[links]\nkind = 'virtual'\n", ["unknown section", "'links'", "[link]", "[gate]"]),
    ("[link]\nchanel = 'can0'\n", ["unknown key", "'chanel'", "[link]", "channel", "profile"]),
    ("[link]\nsilence_timeout_s = 'fast'\n",
     ["[link] silence_timeout_s", "'fast'", "must be a finite number"]),
    ("[link]\nsilence_timeout_s = nan\n", ["[link] silence_timeout_s", "nan", "finite number"]),
    ("[model]\nseed = 1.5\n", ["[model] seed", "1.5", "must be an integer"]),
    ("[model]\nseed = true\n", ["[model] seed", "True", "must be an integer"]),
    ("[estimate]\nlearn = 1\n", ["[estimate] learn", "1", "must be true or false"]),
    ("[link]\nchannel = 0\n", ["[link] channel", "0", "non-empty string"]),
    ("[link]\nchannel = ''\n", ["[link] channel", "''", "non-empty string"]),
    ("[gate]\nrated_mass_kg = 60.0\n",
     ["[gate] rated_mass_kg", "60.0", "out of range", "[0.01, 50]"]),
    ("[gate]\nmin_change_mass_kg = 0.01\n", ["[gate] min_change_mass_kg", "remove it"]),
    ("[gate]\nend_effector_mass_kg = 0.7\n", ["unknown key", "'end_effector_mass_kg'"]),
    ("[link]\nsilence_timeout_s = 0.001\n",
     ["[link] silence_timeout_s", "0.001", "out of range", "[0.005, 60]"]),
    ("[log]\nstatus_period_s = 0\n", ["[log] status_period_s", "0.0", "[0.05, 60]"]),
    ("[link]\nkind = 'can'\n",
     ["[link] kind", "'can'", "valid values are", "'socketcan'", "'replay'"]),
    ("[link]\nprofile = 'FD'\n", ["[link] profile", "'FD'", "'fd', 'classic'"]),
    ("[log]\nformat = 'xml'\n", ["[log] format", "'xml'", "'json', 'text'"]),
    ("[log]\nlevel = 'verbose'\n", ["[log] level", "'verbose'", "'debug'"]),
    ("[log]\nstatus_line = 'yes'\n", ["[log] status_line", "'yes'", "'auto', 'on', 'off'"]),
    ("[model]\nkind = 'BEM'\n", ["[model] kind", "'BEM'", "'IEM'"]),
    ("link = 3\n", ["[link] must be a table", "3"]),
    ("[link]\nkind = 'replay'\nchannel = 'traffic'\n",
     ["[link] channel", "'traffic'", "replay channel is a log file", ".blf", ".trc"]),
])
def test_bad_values_name_key_value_and_what_is_valid(tmp_path, text, parts):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert str(path) in message
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"


def test_bad_toml_names_the_file_and_the_place(tmp_path):
    path = write(tmp_path, "[link]\nkind = socketcan\n")
    with pytest.raises(ConfigError, match=r"cell\.toml: not valid TOML: .*line 2"):
        load_config(path)


@pytest.mark.parametrize(("what", "make", "message"), [
    ("5,000 nested brackets", lambda p: p.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n"),
     "arrays or inline tables nested more than 32 deep on line 1; a configuration file nests "
     "them at most 32 deep"),
    ("5,000 nested inline tables", lambda p: p.write_text("[link]\nx = " + "{a = " * 5000 + "1"
                                                          + "}" * 5000 + "\n"),
     "nested more than 32 deep on line 2"),
    ("a FIFO", os.mkfifo, "cannot read the configuration file: it is a FIFO (named pipe); "
                          "valid is a regular file"),
    ("2 MB", lambda p: p.write_text("# " + "x" * 2_000_000 + "\n"),
     "cannot read the configuration file: it holds 1.91 MB; valid is at most 1 MB"),
])
def test_a_file_out_of_bounds_is_a_clear_error_at_once(tmp_path, what, make, message):
    """Nesting that made Python's TOML parser raise RecursionError, a FIFO that blocked the
    start for good, a file of any size: each a ConfigError (exit 78), at once."""
    path = tmp_path / "cell.toml"
    make(path)
    with within(10), pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: {message}" or message in str(info.value), what


def test_missing_file_says_it_cannot_be_read(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.toml: cannot read the configuration file: "
                                          r"it does not exist"):
        load_config(tmp_path / "nope.toml")


def test_config_error_is_an_invalid_input_error():
    from iem.errors import IemError, InvalidInputError

    assert issubclass(ConfigError, InvalidInputError) and issubclass(ConfigError, IemError)


def test_replay_channel_with_a_log_suffix_is_accepted():
    cfg = config_from_dict({"link": {"kind": "replay", "channel": "traffic.blf"}})
    assert cfg.link.channel == "traffic.blf"


# -- the systemd unit and the CAN set-up script -----------------------------------------------
DEPLOY = EXAMPLE.parent


def test_systemd_unit_parses_and_is_a_notify_service_with_a_watchdog():
    import configparser

    unit = configparser.ConfigParser(interpolation=None, strict=True)
    unit.optionxform = str  # systemd keys are case-sensitive
    unit.read_string((DEPLOY / "iem.service").read_text())
    assert {"Unit", "Service", "Install"} <= set(unit.sections())
    svc = unit["Service"]
    assert svc["Type"] == "notify"
    assert float(svc["WatchdogSec"]) > 0
    assert re.fullmatch(r"\S+/iem run --config /etc/iem/cell\.toml", svc["ExecStart"])
    assert svc["Restart"] == "on-failure" and svc["KillSignal"] == "SIGTERM"
    assert svc["StateDirectory"] == "iem" and svc["User"] not in ("", "root")
    assert "PrivateNetwork" not in svc  # CAN needs the host's network namespace
    env = dict(kv.split("=", 1) for kv in svc["Environment"].split())
    assert env["OPENBLAS_NUM_THREADS"] == "1"  # small solves: BLAS threads only contend
    assert svc["ReadWritePaths"] == "/var/lib/iem" and svc["ProtectSystem"] == "strict"
    assert "MemoryDenyWriteExecute" not in svc  # libffi closures need executable pages
    assert svc["StandardOutput"] == "null"  # the journal: JSON logs only, no summary in words


def test_setup_vcan_script_is_valid_bash_and_has_help():
    import subprocess

    script = DEPLOY / "setup-vcan.sh"
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    # only --help and argument errors: never a command that would change interfaces
    done = subprocess.run(["bash", str(script), "--help"], capture_output=True, text=True)
    assert done.returncode == 0
    assert "usage:" in done.stdout and "vcan [NAME]" in done.stdout
    assert "can IFACE [BITRATE DBITRATE]" in done.stdout and "root" in done.stdout
    bad = subprocess.run(["bash", str(script), "frobnicate"], capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown command 'frobnicate'" in bad.stderr
    bad = subprocess.run(["bash", str(script), "can", "can0", "fast", "5000000"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "BITRATE must be a positive integer" in bad.stderr
