"""Files a user hands over (a model, an arm, a cell.toml, a payload), read within bounds.

Whatever a path names, reading it ends, and in bounded memory: :func:`read_file` reads a
regular file only (a FIFO, a device such as ``/dev/zero``, a directory or a socket is
refused without being read: opening a FIFO does not wait for a writer), and at most
``max_bytes`` of it (a larger file is refused before it is read). :func:`read_toml` reads a
TOML file so: UTF-8 text, at most :data:`MAX_TOML_BYTES`, its arrays and inline tables
nested at most :data:`MAX_TOML_DEPTH` deep (checked before it is parsed: Python's TOML
parser recurses once per level). Each raises the error class its caller gives (the file's
role decides what a bad one means), with a message naming the file and what is valid.
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path

__all__ = ["MAX_TOML_BYTES", "MAX_TOML_DEPTH", "open_regular", "read_file", "read_text",
           "read_toml"]

MAX_TOML_BYTES = 1024 * 1024
"""Largest TOML file read: a cell.toml or a payload file is a few kB."""
MAX_TOML_DEPTH = 32
"""Deepest nesting of arrays and inline tables in a TOML file (a cell.toml nests 2)."""

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _size(n: int) -> str:
    return f"{n / 1024 / 1024:.3g} MB" if n >= 1024 * 1024 else f"{n} bytes"


def _open(path: Path, what: str, error: type[Exception]) -> int:
    """A descriptor of the regular file ``path``, opened without waiting for a FIFO's
    writer (error if it is missing, cannot be opened or is not a regular file)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{path}: cannot read the {what}: it does not exist") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from exc
    try:
        mode = os.fstat(fd).st_mode
    except OSError as exc:
        os.close(fd)
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
        raise error(f"{path}: cannot read the {what}: it is {kind}; valid is a regular file")
    return fd


def open_regular(path, what: str, error: type[Exception]):
    """The regular file ``path`` open for reading in binary (a recording: as long as it is;
    the caller reads it as it goes).

    Raises:
        error: the path does not exist, cannot be opened, or is not a regular file.
    """
    fd = _open(Path(path), what, error)
    return os.fdopen(fd, "rb")


def read_file(path, max_bytes: int, what: str, error: type[Exception]) -> bytes:
    """The bytes of the regular file ``path`` (``what`` names it in messages: "model file":
    ``PATH: cannot read the model file: it is a FIFO (named pipe); valid is a regular file``).

    Raises:
        error: the path does not exist or cannot be opened, is not a regular file, or holds
            more than ``max_bytes``.
    """
    path = Path(path)
    fd = _open(path, what, error)
    try:
        info = os.fstat(fd)
        if info.st_size > max_bytes:
            raise error(f"{path}: cannot read the {what}: it holds {_size(info.st_size)}; "
                        f"valid is at most {_size(max_bytes)}")
        chunks, size = [], 0
        while size <= max_bytes:  # a file that grew since: no more than the bound
            chunk = os.read(fd, max_bytes + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from exc
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > max_bytes:
        raise error(f"{path}: cannot read the {what}: it holds more than "
                    f"{_size(max_bytes)}; valid is at most {_size(max_bytes)}")
    return data


def read_text(path, max_bytes: int, what: str, error: type[Exception],
              encoding: str = "utf-8") -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`read_file`); ``encoding``
    "utf-8-sig" drops a byte-order mark."""
    data = read_file(path, max_bytes, what, error)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{path}: not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}, "
                    f"offset {exc.start}); a {what} must be UTF-8") from exc


def read_toml(path, what: str, error: type[Exception]) -> dict:
    """The TOML document of the file ``path``: UTF-8, at most :data:`MAX_TOML_BYTES`, nested
    at most :data:`MAX_TOML_DEPTH` deep.

    Raises:
        error: as :func:`read_file`, not UTF-8, nested too deep, or not valid TOML.
    """
    text = read_text(path, MAX_TOML_BYTES, what, error)
    line = _too_deep(text, MAX_TOML_DEPTH)
    if line:
        raise error(f"{path}: arrays or inline tables nested more than {MAX_TOML_DEPTH} deep "
                    f"on line {line}; a {what} nests them at most {MAX_TOML_DEPTH} deep")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from exc


def _too_deep(text: str, limit: int) -> int:
    """The line on which the brackets and braces of ``text`` (outside strings and comments)
    first nest deeper than ``limit``; 0 if they never do. Text that is not TOML is left to
    the parser: this only bounds its recursion."""
    depth, line, i, n = 0, 1, 0, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
        elif c == "#":  # a comment, to the end of the line
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        elif c in "\"'":
            quote = c * 3 if text.startswith(c * 3, i) else c
            j = i + len(quote)
            while j < n and not text.startswith(quote, j):
                if text[j] == "\\" and c == '"':
                    j += 1  # an escaped character of a basic string
                elif text[j] == "\n":
                    if len(quote) == 1:
                        break  # a one-line string never crosses a line: the parser says so
                    line += 1
                j += 1
            i = j + len(quote) if text.startswith(quote, j) else j
            continue
        elif c in "[{":
            depth += 1
            if depth > limit:
                return line
        elif c in "]}":
            depth = max(depth - 1, 0)
        i += 1
    return 0
