"""The pylibfranka fake (:mod:`tests.firmware_bridge.franka_fake`) against the real binding.

The constants below are what the binding declares for every name the franka link uses,
written down from pylibfranka 0.21.3 itself: pybind11 puts a function's signature on the
first line of its ``__doc__`` (the wheel's ``_pylibfranka.pyi`` says the same), and the
exceptions' bases are their classes' ``__mro__``.

- Always: the franka link uses no name the constants lack, and the fake has every one of
  them with the declared signature, field type and exception bases.
- Where pylibfranka is installed (``pip install 'iem-payload[franka]'``, the version
  pyproject.toml pins): the constants are what the installed binding declares, and opening a
  robot where none is (127.0.0.1) raises the binding's ``NetworkException``, which the link
  reports as ``ControllerSilent``. No robot is needed.
"""

from __future__ import annotations

import inspect
import re
import tomllib
from pathlib import Path

import pytest

from firmware_bridge.errors import ControllerSilent
from firmware_bridge.links import open_link

from . import franka_fake

REPO = Path(__file__).resolve().parents[2]

VERSION = "0.21.3"
"""The binding the constants were written from."""

SIGNATURES = {
    "Robot.__init__": "(self: Robot, robot_ip_address: str, realtime_config: RealtimeConfig "
                      "= <RealtimeConfig.kEnforce: 0>) -> None",
    "Robot.read_once": "(self: Robot) -> RobotState",
    "Robot.set_load": "(self: Robot, arg0: SupportsFloat | SupportsIndex, arg1: Annotated["
                      "Sequence[SupportsFloat | SupportsIndex], \"FixedSize(3)\"], arg2: "
                      "Annotated[Sequence[SupportsFloat | SupportsIndex], \"FixedSize(9)\"]) "
                      "-> None",
    "Duration.to_sec": "(self: Duration) -> float",
}
"""pybind11's signature of each function the link calls (module prefixes removed)."""

FIELDS = {
    "q": 'Annotated[list[float], "FixedSize(7)"]',
    "dq": 'Annotated[list[float], "FixedSize(7)"]',
    "tau_J": 'Annotated[list[float], "FixedSize(7)"]',
    "time": "Duration",
    "m_load": "float",
    "F_x_Cload": 'Annotated[list[float], "FixedSize(3)"]',
    "I_load": 'Annotated[list[float], "FixedSize(9)"]',
}
"""The ``RobotState`` properties the link reads, and the type each getter returns."""

EXCEPTIONS = {
    "FrankaException": ("Exception", "BaseException", "object"),
    "CommandException": ("RuntimeError", "Exception", "BaseException", "object"),
    "ControlException": ("RuntimeError", "Exception", "BaseException", "object"),
    "InvalidOperationException": ("RuntimeError", "Exception", "BaseException", "object"),
    "NetworkException": ("RuntimeError", "Exception", "BaseException", "object"),
    "RealtimeException": ("RuntimeError", "Exception", "BaseException", "object"),
}
"""The binding's exception classes and their bases, nearest first."""

REALTIME_CONFIG = ("kEnforce", "kIgnore")
"""The members of ``RealtimeConfig``."""

MODULE_NAMES = ("Robot", "RobotState", "Duration", "RealtimeConfig", *EXCEPTIONS)


def _normalised(signature: str) -> str:
    """A pybind11 signature line without its function name and module prefixes."""
    for prefix in ("pylibfranka._pylibfranka.", "collections.abc.", "typing."):
        signature = signature.replace(prefix, "")
    return signature[signature.index("("):].strip()


def _size(annotation: str) -> int | None:
    found = re.search(r'"FixedSize\((\d+)\)"', annotation)
    return int(found.group(1)) if found else None


# -- the link uses nothing the constants lack ------------------------------------------------
def test_the_constants_cover_every_name_the_link_uses():
    source = (REPO / "firmware_bridge" / "franka_link.py").read_text()
    methods = set(re.findall(r"\brobot\.(\w+)\(", source))
    fields = set(re.findall(r"\brs\.(\w+)", source))
    names = set(re.findall(r"\b(?:api|pylibfranka)\.(\w+)", source))
    assert methods == {"read_once", "set_load"}, methods  # (a new one needs its signature)
    assert {f"Robot.{m}" for m in methods} <= set(SIGNATURES)
    assert fields <= set(FIELDS), fields - set(FIELDS)
    assert names <= set(MODULE_NAMES), names - set(MODULE_NAMES)


# -- the fake against the constants (always) -------------------------------------------------
def test_the_fake_has_the_binding_classes_and_exception_bases():
    fake = franka_fake.module()
    for name in MODULE_NAMES:
        assert hasattr(fake, name), f"the fake lacks pylibfranka.{name}"
    for name, bases in EXCEPTIONS.items():
        assert tuple(c.__name__ for c in getattr(fake, name).__mro__[1:]) == bases, name
    for member in REALTIME_CONFIG:
        assert hasattr(fake.RealtimeConfig, member), member


def test_the_fake_robot_takes_the_binding_arguments():
    """``Robot(robot_ip_address, realtime_config=kEnforce)``; the fake's own test controls
    come after them, with defaults."""
    params = list(inspect.signature(franka_fake.Robot).parameters.values())
    declared = re.findall(r"(?:\(|, )(\w+): ", SIGNATURES["Robot.__init__"])[1:]  # no self
    assert [p.name for p in params[:len(declared)]] == declared
    assert params[1].default == franka_fake.RealtimeConfig.kEnforce
    assert all(p.default is not inspect.Parameter.empty for p in params[len(declared):])


def test_the_fake_set_load_takes_what_the_binding_takes():
    """Three positional arguments, no names (pybind11's ``arg0``..``arg2``), of the declared
    sizes; anything else is pybind11's TypeError."""
    sizes = [_size(a) for a in re.split(r"arg\d: ", SIGNATURES["Robot.set_load"])[1:]]
    assert sizes == [None, 3, 9]
    robot = franka_fake.Robot(free_running=True)
    robot.set_load(1.5, [0.0, 0.0, 0.05], [0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01])
    assert robot.load[0] == 1.5
    with pytest.raises(TypeError):
        robot.set_load(1.5, [0.0, 0.0], [0.0] * 9)
    with pytest.raises(TypeError):
        robot.set_load(1.5, [0.0] * 3, [0.0] * 6)
    with pytest.raises(TypeError):
        robot.set_load(load_mass=1.5, F_x_Cload=[0.0] * 3, load_inertia=[0.0] * 9)


def test_the_fake_robot_state_has_the_binding_fields_and_types():
    state = franka_fake.Robot(free_running=True).read_once()
    assert isinstance(state, franka_fake.RobotState)
    for name, returns in FIELDS.items():
        value = getattr(state, name)
        if returns == "float":
            assert isinstance(value, float), name
        elif returns == "Duration":
            assert isinstance(value, franka_fake.Duration), name
            assert isinstance(value.to_sec(), float), name
        else:  # pybind11 returns a std::array as a list of its fixed size
            assert isinstance(value, list) and len(value) == _size(returns), name
            assert all(isinstance(v, float) for v in value), name


# -- the constants against the installed binding ---------------------------------------------
def _real():
    return pytest.importorskip(
        "pylibfranka", reason="pylibfranka is not installed (pip install "
        "'iem-payload[franka]'); the fake was checked against the constants only")


def test_the_pin_is_the_version_the_constants_were_written_from():
    extra = tomllib.loads((REPO / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]["franka"]
    assert extra == [f"pylibfranka=={VERSION}"]


def test_the_constants_are_what_the_installed_binding_declares():
    real = _real()
    assert real.__version__ == VERSION, (
        f"pylibfranka {real.__version__} is installed; the constants were written from "
        f"{VERSION}: check them against it and update the pin")
    for qualified, signature in SIGNATURES.items():
        cls, name = qualified.split(".")
        doc = getattr(getattr(real, cls), name).__doc__
        assert _normalised(doc.splitlines()[0]) == signature, qualified
    for name, returns in FIELDS.items():
        prop = inspect.getattr_static(real.RobotState, name)
        assert isinstance(prop, property), name
        assert _normalised(prop.fget.__doc__.splitlines()[0]) == \
            f"(self: RobotState) -> {returns}", name
    for name, bases in EXCEPTIONS.items():
        assert tuple(c.__name__ for c in getattr(real, name).__mro__[1:]) == bases, name
    assert tuple(real.RealtimeConfig.__members__) == REALTIME_CONFIG


def test_without_a_robot_the_real_binding_is_a_silent_controller():
    """Nothing listens for the FCI on 127.0.0.1: the binding raises its NetworkException at
    once, and the link reports that as the controller silent, naming the class."""
    _real()
    with pytest.raises(ControllerSilent, match=r"Franka robot '127\.0\.0\.1': connecting "
                                               r"failed: NetworkException"):
        open_link("franka", "127.0.0.1")
