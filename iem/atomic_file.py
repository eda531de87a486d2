"""Writing a file atomically, and removing what a writer that was killed left behind.

:func:`write_atomically` writes to a temporary file in the target's directory, which is
flushed, fsynced and then renamed over the target (``os.replace``), and the directory is
fsynced: a crash or an error at any point leaves either the old file or the new one, never a
mix. A process killed while it writes (kill -9, power loss) leaves its temporary file behind,
named ``.<name>.<pid>.<8 hex digits>.tmp`` next to the target;
:func:`remove_stale_temporaries` removes those of dead processes (the service calls it at
start). The model and arm files (:mod:`iem.persistence`) are written so.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
from pathlib import Path

from .errors import ModelFileError

__all__ = ["remove_stale_temporaries", "write_atomically"]


def write_atomically(path, data: bytes, label: str = "model") -> None:
    """Write ``data`` to ``path`` atomically (the previous file survives any failure);
    ``label`` names what the file is in errors.

    Raises:
        ModelFileError: the file cannot be written; the temporary file is removed and
            whatever was at ``path`` is left as it was.
    """
    path = Path(path)
    directory = path.parent
    tmp = directory / _temporary_name(path.name, os.getpid(), secrets.token_hex(4))
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        try:
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    except OSError as exc:
        raise ModelFileError(f"cannot save {label} to {path}: {exc.strerror or exc} "
                             f"(the previous file, if any, is unchanged)") from exc
    _fsync_dir(directory, path)


def _temporary_name(name: str, pid: int, token: str) -> str:
    """The name of :func:`write_atomically`'s temporary file for the target ``name``."""
    return f".{name}.{pid}.{token}.tmp"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. EPERM: it exists, under another user
        return True
    return True


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files an interrupted :func:`write_atomically` of ``path`` left behind.

    Only files of :func:`write_atomically`'s own pattern for this target, in its directory
    (``.<name>.<pid>.<8 hex digits>.tmp``), written by a process that is no longer running
    (a save in progress in a live process, this one included, is left alone). Returns the
    files removed; a file that cannot be removed is left and skipped.
    """
    path = Path(path)
    pattern = re.compile(re.escape(f".{path.name}") + r"\.(\d+)\.[0-9a-f]{8}\.tmp")  # as
    # _temporary_name(path.name, pid, secrets.token_hex(4)) makes them
    removed = []
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return removed  # no directory (yet) or not readable: nothing of ours to clean
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match is None or _pid_alive(int(match.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.is_file() and not entry.is_symlink():
                entry.unlink()
                removed.append(entry)
    return removed


def _fsync_dir(directory: Path, path: Path) -> None:
    """Make the rename durable; filesystems that cannot fsync a directory are tolerated."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return  # e.g. no read permission on the directory: the rename itself is done
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF, errno.EACCES):
            raise ModelFileError(f"model written to {path}, but its directory could not be "
                                 f"synced, so the new file may not survive a power loss: "
                                 f"{exc.strerror or exc}") from exc
    finally:
        os.close(fd)
