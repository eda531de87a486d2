"""The factories a model may name, and the run-time resources they are built from.

A model is plain data, but some of its parts are built by code: the robot model of the
physics (``dynamics``), the learners' extra training samples (``coverage``, ``reversal``). A
model names such a part by a spec, ``"module:function"`` or ``"module:function@ARG"``, and
the spec is looked up in :data:`FACTORIES`, one fixed table: a spec that is not a key of it is
refused (:class:`iem.errors.InvalidInputError`, naming the spec and the valid ones) and
nothing is imported for it. A model file is handed between people (a bug report); what it
names must be data, never code to run. The keys are spelt as the functions' import paths,
which a reader recognises, but they are names: the target each one is imported from, lazily
when a spec of it is first built (``iem`` imports no ``sim`` module otherwise), is the
table's value. Code may add a row (:func:`register_factory`); a file never can.

``ARG`` is one of the names the factory takes (an end effector's name: ``franka_hand``,
``none``), or a reference to a resource by its content, ``KIND:CRC32`` (eight hex digits,
e.g. ``arm:1a2b3c4d``: an arm, :class:`sim.arm.ArmParams`, whose state has that CRC32),
never a path: a path ties a model to one machine's directories, and a file under it may
change while the model stays.

The resource itself is given at run time by whoever runs the model (the cell's ``[model]
arm`` and ``[arm] end_effector``, ``--arm``), to :func:`iem.persistence.load_model` as
``resources={"arm": arm}``, which refuses a model that references a resource it was not
given, or another one. Once accepted, the loader hands the resource to :func:`provide`,
which keeps it in a table of this process keyed by its reference; a factory built later
finds it there. Why a table keyed by content rather than the loader's argument passed down,
or a context manager around the load: the specs must stay plain strings (a model saves,
copies and pickles them as data), and a factory is built when first needed, perhaps after
the load returned and in a training thread, by a model class that knows nothing of the
loader. Keyed by content, an entry can only ever be the resource a spec means: a reference
finds exactly the content it names, or nothing (:func:`build` then says which resource to
give). Code that makes a model for a resource it holds (``iem train``) provides it the same
way (:func:`sim.arm.arm_spec`).
"""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from .errors import InvalidInputError

SPEC_KEYS = ("coverage", "reversal", "dynamics")
"""The keys of a model's state (at any depth) whose str values are factory specs."""


@dataclass(frozen=True)
class Factory:
    """One row of :data:`FACTORIES`.

    Attributes:
        target: ``"module:function"`` it is imported from when first built.
        names: the names it takes as ``ARG`` (passed as the str).
        resource: the kind of resource it takes as ``ARG`` (a reference, ``KIND:CRC32``; the
            resource is passed), or None.
    """

    target: str
    names: tuple[str, ...] = ()
    resource: str | None = None

    def form(self, key: str) -> str:
        """How a spec of it is written: ``key`` and, in brackets, the ``ARG`` it takes."""
        args = [*self.names, *([f"{self.resource}:CRC32"] if self.resource else [])]
        return f"{key}[@{'|'.join(args)}]" if args else key


FACTORIES: dict[str, Factory] = {
    "sim.arm:nominal_dynamics": Factory("sim.arm:nominal_dynamics",
                                        names=("franka_hand", "none")),
    "sim.arm:arm_dynamics": Factory("sim.arm:arm_dynamics", resource="arm"),
    "sim.coverage:reversed_velocities": Factory("sim.coverage:reversed_velocities",
                                                resource="arm"),
    "sim.coverage:other_velocities": Factory("sim.coverage:other_velocities"),
}
"""Every factory a model may name: ``spec -> Factory``. Without ``ARG`` each is called with
none (the nominal arm, the Franka Hand). Code may add a row (:func:`register_factory`); a
file never can."""

RESOURCE_KINDS = ("arm",)
"""The kinds of resource a spec may reference: ``arm``, the arm a model runs on
(:class:`sim.arm.ArmParams`: an arm file, or the nominal arm carrying a tool)."""

def register_factory(spec: str, target: str | None = None, names: tuple[str, ...] = (),
                     resource: str | None = None) -> None:
    """Let models name ``spec`` (``"module:function"``), built from ``target`` (default: the
    spec itself) with the ``names`` or the ``resource`` kind it takes as ``ARG``: how code
    (a test's stand-in robot, say) adds a factory, as :func:`iem.model_kinds.register_model`
    adds a model kind."""
    target = spec if target is None else target
    for text, what in ((spec, "spec"), (target, "target")):
        if not isinstance(text, str) or text.count(":") != 1 or "@" in text:
            raise InvalidInputError(f"factory {what} must be 'module:function', got {text!r}")
    if resource is not None and resource not in RESOURCE_KINDS:
        raise InvalidInputError(f"resource kind {resource!r} is not one of "
                                f"{', '.join(RESOURCE_KINDS)}")
    FACTORIES[spec] = Factory(target, tuple(names), resource)


_REFERENCE = re.compile(r"([a-z_]+):([0-9a-f]{8})")


@runtime_checkable
class Resource(Protocol):
    """What a resource offers: its content hash and what a model file records of it."""

    crc32: int
    """CRC32 of its content (its state), the hash a reference names."""

    def record(self) -> dict:
        """``{"crc32", "source", ...}``, as a model file records it (for messages)."""


def reference(kind: str, resource) -> str:
    """The reference ``KIND:CRC32`` of ``resource`` (its ``crc32``, eight hex digits)."""
    if kind not in RESOURCE_KINDS:
        raise InvalidInputError(f"resource kind {kind!r} is not one of "
                                f"{', '.join(RESOURCE_KINDS)}")
    return f"{kind}:{int(resource.crc32) & 0xFFFFFFFF:08x}"


def parse_reference(text: str) -> tuple[str, int] | None:
    """``(kind, crc32)`` of a reference ``KIND:CRC32``; None if ``text`` is not one."""
    match = _REFERENCE.fullmatch(text)
    if match is None or match.group(1) not in RESOURCE_KINDS:
        return None
    return match.group(1), int(match.group(2), 16)


_PROVIDED: dict[str, object] = {}


def provide(kind: str, resource) -> str:
    """Make ``resource`` of ``kind`` available to the factories of this process under its
    reference, and return the reference (``KIND:CRC32``). Keyed by content: providing the
    same content again changes nothing."""
    ref = reference(kind, resource)
    _PROVIDED[ref] = resource
    return ref


def valid_specs() -> str:
    """The specs a model may name, as a message lists them."""
    return ", ".join(FACTORIES[k].form(k) for k in sorted(FACTORIES))


def parse(spec, what: str) -> tuple[str, str | None]:
    """``(key, ARG or None)`` of ``spec`` if :data:`FACTORIES` has it with an ``ARG`` it takes;
    ``what`` names the setting in the error. Imports nothing.

    Raises:
        InvalidInputError: anything else, naming the spec and the valid ones.
    """
    if not isinstance(spec, str):
        raise InvalidInputError(f"{what} {spec!r} is not a str naming a factory; valid are "
                                f"{valid_specs()}")
    key, at, arg = spec.partition("@")
    factory = FACTORIES.get(key)
    if factory is None:
        raise InvalidInputError(f"{what} {spec!r} is not a factory a model may name; valid "
                                f"are {valid_specs()}")
    if not at:
        return key, None
    ref = parse_reference(arg)
    if arg in factory.names or (ref is not None and ref[0] == factory.resource):
        return key, arg
    takes = factory.form(key).partition("[")[2].rstrip("]") or "no @ARG"
    raise InvalidInputError(f"{what} {spec!r}: {key} takes {takes}, not {arg!r} (a model "
                            f"names a file by content, never by path); valid are "
                            f"{valid_specs()}")


def referenced(spec: str) -> tuple[str, int] | None:
    """``(kind, crc32)`` of the resource a valid ``spec`` references; None if none."""
    arg = spec.partition("@")[2]
    return parse_reference(arg) if arg else None


def build(spec: str, what: str):
    """The object the factory of ``spec`` makes: ``function()``, ``function(NAME)``, or
    ``function(resource)`` with the resource its reference names (:func:`provide`);
    ``what`` names the setting in errors.

    Raises:
        InvalidInputError: the spec is not in :data:`FACTORIES`, its resource was not given
            to this process, or its target cannot be imported.
    """
    key, arg = parse(spec, what)
    target = FACTORIES[key].target
    module, _, name = target.partition(":")
    try:
        factory = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise InvalidInputError(f"{what} {spec!r}: its factory {target} cannot be imported: "
                                f"{exc}") from exc
    if arg is None:
        return factory()
    ref = parse_reference(arg)
    if ref is None:  # a name
        return factory(arg)
    if arg not in _PROVIDED:
        kind = ref[0]
        raise InvalidInputError(f"{what} {spec!r} references the {kind} {arg}, which was not "
                                f"given: load the model with it (the cell's [model] arm and "
                                f"[arm] end_effector, --arm; resources={{{kind!r}: ...}})")
    return factory(_PROVIDED[arg])


def specs_in(state: dict, path: str = "") -> list[tuple[str, str]]:
    """``(key path, spec)`` of every factory spec (:data:`SPEC_KEYS`, a str) in ``state``
    and its nested maps."""
    out = []
    for key, value in state.items():
        where = f"{path}.{key}" if path else str(key)
        if isinstance(value, dict):
            out += specs_in(value, where)
        elif key in SPEC_KEYS and isinstance(value, str):
            out.append((where, value))
    return out
