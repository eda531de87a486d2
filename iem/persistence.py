"""Saving and loading estimators: one msgpack file per model, written atomically.

A model file is one msgpack map::

    {"schema": "iem-payload-model", "version": <VERSION>, "kind": "IEM",
     "crc32": <zlib.crc32 of state and version>, "state": <msgpack bytes of model.to_state()>}

The state is packed on its own so that its CRC can be checked before anything in it is
trusted. A model trained for a calibrated arm (``iem train --arm``) also carries
``"arm": {"crc32": <the arm file's state CRC>, "source": <its file name>}`` (and
``"end_effector"``, the label of :mod:`sim.end_effector`, when it is not the hand), covered by the
file's CRC (``crc32(arm map, crc32(state))``); it is the model's ``trained_arm`` attribute
(None for the nominal arm), and :func:`check_arm` refuses to run the model with another arm.
A model trained on another payload family than the paper's (``iem train --family generic``)
records it as ``"family"`` (also covered by the CRC; its ``trained_family`` attribute), so the
service can refuse to train new bags of it with another family's simulators. The CRC then
continues over the version (its msgpack bytes; not in a version-1 file), so that a damaged
version cannot send a state through another version's migrations.
The arm file (:mod:`sim.arm`) is written and read by the same functions under its own schema
(``schema=``, ``label=``).

``kind`` is the estimator's ``name``, looked up in :data:`iem.model_kinds.MODELS` (name ->
``"module:Class"``, imported only when a file of that kind is loaded, as python-can does with
its interfaces); the class rebuilds itself with ``Class.from_state(state)``.

``version`` is the schema version the file was written at; files are written at
:data:`VERSION`. A file of an older version is loaded through the steps of
:mod:`iem.migrations`, which bring its state to the newest layout before ``from_state`` sees
it; a file of a newer version than this build knows is refused. The names a file holds (its
kind's class, the factory specs ``coverage``, ``reversal``, ``dynamics`` in its state) go
through :data:`iem.migrations.ALIASES` at load, so that a name that changes keeps its files
loading.

A model file holds data only: its kind and factory specs are looked up in fixed tables
(:data:`iem.model_kinds.MODELS`, :data:`iem.factories.FACTORIES`), and a spec the table lacks
is refused with nothing imported. It names no path: the arm a model runs on is referenced by
content (``...@arm:CRC32``, its ``arm`` record's CRC) and given at run time,
``load_model(path, resources={"arm": arm})``; without it, or with another, the file is refused
naming both.

A file is read within bounds, whoever made it: a regular file only (a FIFO or a device is
refused without being read) of at most :data:`MAX_MODEL_BYTES` (a model is kilobytes to a
few MB); the header's fields one by one (:func:`iem.bounded_msgpack.map_fields`: an unknown
field is refused by its name before its value is read, the arm record's keys are checked
too); the state unpacked within a budget of :data:`STATE_BUDGET` times its size and 4 MB
(:func:`iem.bounded_msgpack.unpack`), so that no file of tiny containers fills the memory;
every number of the state checked by its key's rule before the model is rebuilt
(:mod:`iem.state_checks`: finite, in range, covariances positive semidefinite); and a key
of the state (at any depth: a learner's, the detector's) that the model does not keep,
which its ``to_state`` does not give back, is refused.

A file is written atomically (:mod:`iem.atomic_file`: a crash or an error at any point leaves
either the old file or the new one). Every problem with a file, on saving or on loading,
raises :class:`iem.errors.ModelFileError` naming the file and what was wrong; nothing else
escapes for a bad file.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from pathlib import Path

import msgpack

from . import bounded_msgpack, model_kinds
from .atomic_file import write_atomically
from .errors import InvalidInputError, ModelFileError
from .factories import parse, provide, referenced, specs_in
from .migrations import VERSION, migrate, with_current_paths
from .state_checks import StateError, check_state
from .user_files import read_file

SCHEMA = "iem-payload-model"
"""The ``schema`` field of every model file."""

_FIELDS: dict[str, type | tuple[type, ...]] = {
    "schema": str, "version": int, "kind": str, "crc32": int, "state": bytes}
_OPTIONAL = ("arm", "family")
"""Header fields a file may hold besides :data:`_FIELDS`."""
_ARM_KEYS = ("crc32", "source", "end_effector", "description")
"""The keys of the arm record (:func:`arm_record_of`)."""

MAX_MODEL_BYTES = 32 * 1024 * 1024
"""Largest model (or arm) file read: a model is kilobytes to a few MB (2,000 bags, the
budget's default, take about 10 MB)."""
MAX_FIELD_BYTES = 64 * 1024
"""Largest header field but the state."""
STATE_BUDGET = 8
"""The state unpacks to at most this many times its size (and 4 MB) of Python objects: a
number takes 9 bytes in the file and 32 in Python."""


# -- encoding ----------------------------------------------------------------------------
def _record_crc(arm: dict | None, crc: int, family: str | None = None,
                version: int = VERSION) -> int:
    """The file CRC: the state's, continued over the arm record and the training family if
    there are any, and over the version but in a version-1 file."""
    if arm is not None:
        crc = zlib.crc32(msgpack.packb(arm, use_bin_type=True), crc)
    if family is not None:
        crc = zlib.crc32(family.encode("utf-8"), crc)
    if version != 1:
        crc = zlib.crc32(msgpack.packb(version), crc)
    return crc


def _family_record(model) -> str | None:
    """The training family a model records: None for the paper's (a file without the record
    was trained on it), else its name (``trained_family``)."""
    family = getattr(model, "trained_family", None)
    if family in (None, DEFAULT_FAMILY):
        return None
    if not isinstance(family, str):
        raise ModelFileError(f"model's trained_family {family!r} is not a family name")
    return family


DEFAULT_FAMILY = "paper"
"""The training family of a model file that records none."""


def _arm_record(model) -> dict | None:
    return arm_record_of(getattr(model, "trained_arm", None))


def arm_record_of(arm: dict | None) -> dict | None:
    """The arm record a model file keeps of ``arm`` (``trained_arm``): its CRC32, source,
    end effector and arm model (name and digest), checked."""
    if arm is None:
        return None
    if not (isinstance(arm, dict) and isinstance(arm.get("crc32"), int)
            and isinstance(arm.get("source"), str)):
        raise ModelFileError(f"model's trained_arm {arm!r} is not "
                             "{'crc32': int, 'source': str}")
    out = {"crc32": int(arm["crc32"]), "source": str(arm["source"])}
    if arm.get("end_effector"):
        out["end_effector"] = str(arm["end_effector"])
    if isinstance(arm.get("description"), dict):  # the arm model, by content
        out["description"] = {"name": str(arm["description"].get("name")),
                              "digest": str(arm["description"].get("digest"))}
    return out


def dumps(model, schema: str = SCHEMA) -> bytes:
    """The bytes of a model file for ``model`` (see the module docstring); ``schema``
    names the kind of file (another schema for the arm file).

    Raises:
        ModelFileError: the model's state holds something msgpack cannot pack.
    """
    kind = getattr(model, "name", None)
    if not isinstance(kind, str) or not kind:
        raise ModelFileError(f"cannot save {type(model).__name__}: it has no str 'name' "
                             f"to record as the model kind")
    plain = model.to_state()
    try:
        state = msgpack.packb(plain, use_bin_type=True)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ModelFileError(f"cannot save {kind} model: its state is not plain data "
                             f"(lists, floats, ints, str, None, dicts): {exc}") from exc
    arm = _arm_record(model)
    family = _family_record(model)
    head = {"schema": schema, "version": VERSION, "kind": kind,
            "crc32": _record_crc(arm, zlib.crc32(state), family), "state": state}
    if arm is not None:
        head["arm"] = arm
    if family is not None:
        head["family"] = family
    return msgpack.packb(head, use_bin_type=True)


def check_arm(model, arm_record: dict | None, where: str = "model") -> None:
    """Refuse ``model`` unless it was trained for the arm ``arm_record`` (``{"crc32",
    "source"}`` of an arm file, :func:`sim.arm.arm_record`; None: the nominal arm).

    Raises:
        ModelFileError: the model was trained for another arm (or for none).
    """
    have = getattr(model, "trained_arm", None)
    if (have or {}).get("crc32") != (arm_record or {}).get("crc32"):
        raise ModelFileError(_arm_mismatch(have, arm_record, where))


def _arm_mismatch(have: dict | None, given: dict | None, where: str) -> str:
    """What :func:`check_arm` says of a model trained for the arm ``have`` run with
    ``given`` (records; None: the nominal arm)."""

    def say(r):
        if r is None:
            return ("the default arm model's nominal arm with the end effector 'franka_hand' "
                    "(no arm file)")
        ee = f"the end effector {r.get('end_effector') or 'franka_hand'!r}"
        d = r.get("description")
        model = (f"the arm model {d['name']!r} ({d['digest']})" if d
                 else "the default arm model")
        if r["source"] == "nominal":
            return f"{model}'s nominal arm with {ee} (no arm file)"
        return (f"arm file {r['source']} (CRC32 {r['crc32'] & 0xFFFFFFFF:#010x}, {model}, "
                f"{ee})")

    return (f"{where} was trained for {say(have)} but is run with {say(given)}; use the arm "
            f"it was trained with ([model] arm, [arm] model and end_effector; --arm, "
            f"--arm-model and --end-effector), or make a model for this arm with 'iem train "
            f"--arm ARM --arm-model MODEL --out MODEL_FILE'")


def _given_resources(state: dict, arm: dict | None, resources: Mapping, where: str) -> dict:
    """The resources of ``resources`` that the specs of ``state`` reference, checked: every
    spec is one of :data:`iem.factories.FACTORIES` (nothing is imported), every resource it
    references was given with that content (an arm: the file's record ``arm``, else refused
    naming both, as :func:`check_arm` does)."""
    needed = {}
    for key, spec in specs_in(state):
        try:
            parse(spec, key.rpartition(".")[2])
        except InvalidInputError as exc:
            raise ModelFileError(f"{where}: {exc}") from exc
        ref = referenced(spec)
        if ref is None:
            continue
        kind, crc = ref
        given = resources.get(kind)
        have = getattr(given, "crc32", None)
        if kind == "arm" and (arm is None or have != arm["crc32"]):
            record = None if given is None else given.record()
            raise ModelFileError(_arm_mismatch(arm, record, where))
        if have != crc:
            raise ModelFileError(f"{where}: its {key} {spec!r} references the {kind} of CRC32 "
                                 f"{crc:#010x}, but is given "
                                 f"{'none' if given is None else f'CRC32 {have:#010x}'}")
        needed[kind] = given
    return needed


def _unpack_state(data: bytes, where: str):
    """The state's bytes unpacked within :data:`STATE_BUDGET` (ModelFileError if not)."""
    try:
        return bounded_msgpack.unpack(data, STATE_BUDGET * len(data) + 4 * 2**20)
    except bounded_msgpack.NotMsgpack as exc:
        raise ModelFileError(f"{where}: the state is not valid msgpack: {exc}") from exc
    except bounded_msgpack.BoundsError as exc:
        raise ModelFileError(f"{where}: the state {exc}") from exc


def keys_not_kept(given, kept, path: str = "") -> list[str]:
    """The keys of the plain data ``given`` (at any depth, paths like
    ``ensemble.learners[1].zzz``) that ``kept`` lacks where ``given`` has them: what a model
    rebuilt from ``given`` does not give back in its ``to_state``."""
    out = []
    if isinstance(given, dict) and isinstance(kept, dict):
        for key, value in given.items():
            where = f"{path}.{key}" if path else str(key)
            if key not in kept:
                out.append(where)
            else:
                out += keys_not_kept(value, kept[key], where)
    elif isinstance(given, list) and isinstance(kept, list) and len(given) == len(kept):
        for i, (a, b) in enumerate(zip(given, kept, strict=True)):
            out += keys_not_kept(a, b, f"{path}[{i}]")
    return out


def _refuse_keys_not_kept(model, state: dict, where: str, kind: str, label: str) -> None:
    """ModelFileError if ``state`` holds a key that ``model``, rebuilt from it, does not keep
    (an unknown key: a typo, another program's, a planted one)."""
    kept = msgpack.unpackb(msgpack.packb(model.to_state(), use_bin_type=True), raw=False,
                           strict_map_key=False)
    unknown = keys_not_kept(state, kept)
    if unknown:
        raise ModelFileError(f"{where}: the state holds the unknown key(s) "
                             f"{', '.join(unknown[:10])}"
                             f"{f' and {len(unknown) - 10} more' if len(unknown) > 10 else ''}"
                             f"; a {label} of kind {kind!r} keeps none of them")


def loads(data: bytes, registry: Mapping[str, str] | None = None, source: str = "<bytes>",
          schema: str = SCHEMA, label: str = "model", resources: Mapping | None = None):
    """The model in the bytes of a model file; ``source`` names them in error messages,
    ``schema`` is the schema expected and ``label`` what the file is called in them;
    ``resources`` as for :func:`load_model`.

    Raises:
        ModelFileError: the bytes are not a valid model file of a registered kind, a spec in
            it is not one of :data:`iem.factories.FACTORIES`, or a resource it references
            was not given, or given with other content.
    """
    where = f"{label} file {source}"
    head = _checked_head(data, where, schema)
    arm, family, version = head.get("arm"), head.get("family"), head["version"]
    state_bytes = head["state"]
    crc = _record_crc(arm, zlib.crc32(state_bytes), family, version)
    if crc != head["crc32"]:
        raise ModelFileError(f"{where} is corrupt: the state's CRC32 is {crc:#010x}, the "
                             f"file records {head['crc32'] & 0xFFFFFFFF:#010x}")
    cls = model_kinds.model_class(head["kind"], model_kinds.MODELS if registry is None
                                   else registry, where)
    state = _unpack_state(state_bytes, where)
    if not isinstance(state, dict):
        raise ModelFileError(f"{where}: the state is a {type(state).__name__}, expected a map")
    try:
        state = with_current_paths(migrate(head["kind"], state, version, {"arm": arm}))
    except Exception as exc:  # any failure to bring the state up is a bad file
        raise ModelFileError(f"{where}: the state of version {version} cannot be brought to "
                             f"version {VERSION}: {type(exc).__name__}: {exc}") from exc
    try:
        check_state(state)
    except StateError as exc:
        raise ModelFileError(f"{where}: the state's {exc}") from None
    for kind, resource in _given_resources(state, arm, resources or {}, where).items():
        provide(kind, resource)
    try:
        model = cls.from_state(state)
    except Exception as exc:  # any failure to rebuild from the file is a bad file
        raise ModelFileError(f"{where}: the state does not describe a valid {head['kind']} "
                             f"{label}: {type(exc).__name__}: {exc}") from exc
    _refuse_keys_not_kept(model, state, where, head["kind"], label)
    if arm is not None:
        model.trained_arm = arm_record_of(arm)
    if schema == SCHEMA:  # a model file without the record was trained on the paper's
        model.trained_family = family if family is not None else DEFAULT_FAMILY
    return model


def _checked_head(data: bytes, where: str, schema: str) -> dict:
    """The header map of a model file's bytes, its fields checked (not yet its CRC): the
    schema, a version this build reads, the fields' types, the arm and family records.

    Raises:
        ModelFileError: it is not the header of a model file of ``schema`` this build reads.
    """
    if not data:
        raise ModelFileError(f"{where} is empty")
    bounds = {key: len(data) if key == "state" else MAX_FIELD_BYTES
              for key in (*_FIELDS, *_OPTIONAL)}
    try:
        head = bounded_msgpack.map_fields(data, bounds)
    except bounded_msgpack.NotAMap as exc:
        raise ModelFileError(f"{where} holds a {exc.type_name}, not the map of a model file "
                             f"(keys {sorted(_FIELDS)})") from exc
    except bounded_msgpack.NotMsgpack as exc:
        raise ModelFileError(f"{where} is not a msgpack model file (truncated or corrupt): "
                             f"{exc}") from exc
    except bounded_msgpack.BoundsError as exc:
        raise ModelFileError(f"{where} {exc}") from exc
    for key in ("schema", "version"):
        if key not in head:
            raise ModelFileError(f"{where} lacks the field {key!r}, so it is not a model "
                                 f"file (a model file has {sorted(_FIELDS)})")
    if head["schema"] != schema:
        raise ModelFileError(f"{where} has schema {head['schema']!r}, expected {schema!r}")
    version = head["version"]
    if type(version) is int and version > VERSION:
        raise ModelFileError(f"{where} has schema version {version}, newer than this build's "
                             f"{VERSION}: it was written by a newer iem; update iem to load it")
    if type(version) is not int or version < 1:
        raise ModelFileError(f"{where} has version {version!r}; this build reads versions 1 "
                             f"to {VERSION}")
    for key, typ in _FIELDS.items():
        if key not in head:
            raise ModelFileError(f"{where} lacks the field {key!r} (a model file has "
                                 f"{sorted(_FIELDS)})")
        value = head[key]
        if not isinstance(value, typ) or isinstance(value, bool):
            raise ModelFileError(f"{where}: field {key!r} is a {type(value).__name__}, "
                                 f"expected {typ.__name__}")
    arm = head.get("arm")
    if arm is not None and not (isinstance(arm, dict) and isinstance(arm.get("crc32"), int)
                                and isinstance(arm.get("source"), str)):
        raise ModelFileError(f"{where}: field 'arm' is {arm!r}, expected "
                             "{'crc32': int, 'source': str}")
    unknown = sorted(map(str, set(arm or {}) - set(_ARM_KEYS)))
    if unknown:
        raise ModelFileError(f"{where}: field 'arm' holds the unknown key(s) {unknown}; "
                             f"valid are {list(_ARM_KEYS)}")
    family = head.get("family")
    if family is not None and not isinstance(family, str):
        raise ModelFileError(f"{where}: field 'family' is {family!r}, expected a family name")
    return head


# -- files -------------------------------------------------------------------------------
def save_model(model, path, schema: str = SCHEMA, label: str = "model") -> None:
    """Write ``model`` to ``path`` atomically (:func:`iem.atomic_file.write_atomically`: the
    previous file survives any failure); ``schema`` and ``label`` as for :func:`loads`.

    Raises:
        ModelFileError: the state cannot be packed, or the file cannot be written; the
            temporary file is removed and whatever was at ``path`` is left as it was.
    """
    path = Path(path)
    try:
        data = dumps(model, schema)
    except ModelFileError as exc:
        raise ModelFileError(f"cannot save {label} to {path}: {exc}") from exc
    write_atomically(path, data, label)


def load_model(path, registry: Mapping[str, str] | None = None, schema: str = SCHEMA,
               label: str = "model", resources: Mapping | None = None):
    """The model saved at ``path``.

    Args:
        path: the model file.
        registry: ``kind -> "module:Class"`` to resolve the model's kind (default
            :data:`iem.model_kinds.MODELS`).
        schema, label: as for :func:`loads` (the arm file has its own).
        resources: what the model runs on, given at run time: ``{"arm": arm}``
            (:class:`sim.arm.ArmParams`: the configured arm file, or the nominal arm
            carrying the configured tool; None: the nominal arm). A model whose specs
            reference an arm (``...@arm:CRC32``) needs the arm of that content, which is
            then provided to the factories (:mod:`iem.factories` says why so).

    Raises:
        ModelFileError: the file is missing, unreadable, not a regular file, larger than
            :data:`MAX_MODEL_BYTES`, empty, truncated, corrupt, of an unknown schema, version
            or kind, its state does not rebuild a model, or as :func:`loads` says.
    """
    path = Path(path)
    data = read_file(path, MAX_MODEL_BYTES, f"{label} file", ModelFileError)
    return loads(data, registry=registry, source=str(path), schema=schema, label=label,
                 resources=resources)
