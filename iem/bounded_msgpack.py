"""msgpack read within bounds: a map's fields one by one, and a value unpacked within a
memory budget.

msgpack packs an empty list in one byte, which Python holds in about 70: a file of a few MB
can unpack to GB. A model file (:mod:`iem.persistence`) is read so that this cannot happen:

- :func:`map_fields` walks the top-level map of ``data`` key by key, refusing an unknown key
  by its name before its value is unpacked, and a value longer than its bound before it is;
- :func:`unpack` unpacks a value while it counts what the Python objects it builds hold (each
  list and map, and the numbers and strings in them), and stops once the count passes
  ``budget`` bytes; no list or map may hold more than :data:`MAX_ITEMS` items.

Both raise :class:`BoundsError` (:class:`NotMsgpack` for bytes that are no msgpack value,
:class:`NotAMap` for a value that is not a map), whose message says what was wrong; the
caller names the file.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

import msgpack

__all__ = ["MAX_ITEMS", "BoundsError", "NotAMap", "NotMsgpack", "map_fields", "unpack"]

MAX_ITEMS = 1 << 20
"""Most items in one list or map (a model's longest list is one item per bag)."""
MAX_KEY_BYTES = 256
"""Longest key of a map read field by field."""

_LIST, _MAP, _FIELD = 72, 232, 80  # bytes of an empty list, an empty dict, a dict's entry
_NUMBER, _STRING = 32, 49  # a float or int and its pointer; an empty str or bytes
_LIMIT = re.compile(r"(\d+) exceeds max_(array|map|str|bin|ext)_len")


class BoundsError(ValueError):
    """Bytes that break a bound, or are not what was expected."""


class NotMsgpack(BoundsError):
    """Bytes that are not one msgpack value (truncated, corrupt, or something else)."""


class NotAMap(BoundsError):
    """One msgpack value, not a map: ``type_name`` is its Python type's name."""

    def __init__(self, type_name: str) -> None:
        super().__init__(f"holds a {type_name}, not a map")
        self.type_name = type_name


def _cost(values: Iterable) -> int:
    cost = 0
    for v in values:
        t = type(v)
        if t is float or t is int:
            cost += _NUMBER
        elif t is str or t is bytes:
            cost += _STRING + len(v)
    return cost


def unpack(data, budget: int):
    """The value packed in ``data`` (maps may have keys of any type), unpacked within
    ``budget`` bytes of Python objects (an estimate that counts every list and map and the
    numbers and strings they hold).

    Raises:
        BoundsError: ``data`` is not one msgpack value, or breaks a bound.
    """
    left = budget

    def charge(n: int) -> None:
        nonlocal left
        left -= n
        if left < 0:
            raise _OverBudget

    def list_hook(items):
        charge(_LIST + 8 * len(items) + _cost(items))
        return items

    def pairs_hook(pairs):
        charge(_MAP + _FIELD * len(pairs) + _cost(k for k, _ in pairs)
               + _cost(v for _, v in pairs))
        return dict(pairs)

    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False, list_hook=list_hook,
                               object_pairs_hook=pairs_hook, max_array_len=MAX_ITEMS,
                               max_map_len=MAX_ITEMS, max_str_len=len(data),
                               max_bin_len=len(data), max_ext_len=0)
    except _OverBudget:
        raise BoundsError(f"unpacks to more than {budget / 2**20:.3g} MB of Python objects "
                          f"from {len(data)} bytes") from None
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        limit = _LIMIT.search(str(exc))
        if limit and limit.group(2) in ("array", "map"):
            raise BoundsError(f"holds a list or map of {limit.group(1)} values; valid is at "
                              f"most {MAX_ITEMS}") from exc
        raise NotMsgpack(f"{type(exc).__name__}: {exc}") from exc


class _OverBudget(Exception):
    pass


def map_fields(data, fields: Mapping[str, int]) -> dict:
    """The top-level map of ``data`` as a dict, read field by field: each key must be one of
    ``fields`` (``key -> the most bytes its value may take``), and is refused by its name
    before its value is read; a key given twice is refused too.

    Raises:
        BoundsError: ``data`` is not one msgpack map, a key is unknown or repeated, or a
            value is longer than its bound.
    """
    view = memoryview(data)
    reader = msgpack.Unpacker(raw=False, max_buffer_size=max(len(data), 1),
                              max_array_len=MAX_ITEMS, max_map_len=MAX_ITEMS)
    reader.feed(data)
    try:
        first = view[0] if len(view) else None
        if first is not None and (0x90 <= first <= 0x9F or first in (0xDC, 0xDD)):
            raise NotAMap("list")  # not unpacked: a list can be anything
        if first is None or not (0x80 <= first <= 0x8F or first in (0xDE, 0xDF)):
            value = unpack(data, 64 * len(data) + 4096)  # a scalar, or no msgpack at all
            raise NotAMap(type(value).__name__)
        n = reader.read_map_header()
        out = {}
        for _ in range(n):
            start = reader.tell()
            reader.skip()
            end = reader.tell()
            if end - start > MAX_KEY_BYTES:
                raise BoundsError(f"has a key of {end - start} bytes; its keys are names")
            key = unpack(view[start:end], 64 * MAX_KEY_BYTES)
            if not isinstance(key, str) or key not in fields:
                raise BoundsError(f"has the unknown field {key!r}; valid are "
                                  f"{', '.join(sorted(fields))}")
            if key in out:
                raise BoundsError(f"has the field {key!r} twice")
            start = reader.tell()
            reader.skip()
            end = reader.tell()
            if end - start > fields[key]:
                raise BoundsError(f"has the field {key!r} of {end - start} bytes; valid is at "
                                  f"most {fields[key]}")
            out[key] = unpack(view[start:end], 64 * (end - start) + 4096)
    except BoundsError:
        raise
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise NotMsgpack(f"{type(exc).__name__}: {exc}") from exc
    if reader.tell() != len(data):
        raise NotMsgpack(f"{len(data) - reader.tell()} bytes after its map")
    return out
