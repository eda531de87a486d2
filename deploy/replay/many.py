"""``iem replay`` of many recordings: a folder, a glob or several paths, in ``--jobs`` processes.

Each recording is replayed exactly as ``iem replay REC`` replays it alone (the same
:func:`deploy.replay.core.replay` with the same options, its model and payload files read in the
process that replays it), so its estimates are the ones a replay of that file alone gives.
The files are spread over ``--jobs N`` processes (:class:`concurrent.futures.ProcessPoolExecutor`,
started with ``spawn``: nothing of the parent's state is shared, each child limits its linear
algebra to one thread, as ``iem`` does, since the parallelism is across files); ``--jobs 1``
replays them one after another in this process.

What a folder holds is every entry :func:`firmware_bridge.recordings.detect_format` takes for
a recording (CAN logs, rosbag2 bag folders, ``.db3``, ``.mcap``, joint-state CSVs; of
``--format`` if given), not descending into other folders; a glob (quoted, so that ``iem``
expands it) keeps the recordings among its matches. A folder or glob without one is an error
naming what was looked for. Outputs are per recording where one recording's are a file:
``--out DIR`` writes ``DIR/<name>.csv`` and ``--save-model DIR`` ``DIR/<name>.msgpack``
(``<name>``: the recording's file name), and ``--json FILE`` one JSON whose
``recordings`` lists, in the order given, each recording's ``file``, ``error`` (null, or why
it failed), ``final_phi`` (the last smoothed estimate) and ``summary`` (the JSON a replay of
that file alone writes). Each summary is printed as its replay ends, then a table over all.

A recording that fails costs that recording: its row says why, the others finish, and
``iem`` exits with status 2. Ctrl-C stops the children.
"""

from __future__ import annotations

import glob
import sys
import time
from pathlib import Path as FsPath

from .job import INPUTS, child_init, inputs_of, replay_one

_GLOB_CHARS = frozenset("*?[")


# -- which recordings -------------------------------------------------------------------------
def _is_recording(path: FsPath, format: str | None) -> bool:
    from firmware_bridge.errors import LogFileError
    from firmware_bridge.recordings import detect_format

    try:
        fmt = detect_format(path)
    except LogFileError:
        return False
    return format is None or fmt == format


def _looked_for(format: str | None) -> str:
    from firmware_bridge.recordings import VALID

    return f"{format} recordings" if format else VALID


def recordings_of(paths, format: str | None = None) -> list[FsPath] | None:
    """The recordings that ``iem replay``'s arguments name, in order, each once; None when
    they are one recording (a file or a bag folder, replayed as one).

    A folder that is no rosbag2 bag stands for the recordings in it, a path that does not
    exist but holds ``*``, ``?`` or ``[`` for the recordings it matches (sorted); any other
    path is taken as given (a missing one fails its own row).

    Raises:
        InvalidInputError: a folder or glob without a recording (of ``format``, if given),
            naming it and what was looked for.
    """
    from iem.errors import InvalidInputError

    paths = [FsPath(p) for p in paths]
    found: dict[FsPath, None] = {}  # in order, each once
    for path in paths:
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            some = [p for p in sorted(path.iterdir()) if _is_recording(p, format)]
            if not some:
                raise InvalidInputError(f"{path}: no recording in this folder; looked for "
                                        f"{_looked_for(format)} (not in its sub-folders)")
        elif not path.exists() and _GLOB_CHARS & set(str(path)):
            matches = sorted(glob.glob(str(path)))
            some = [FsPath(p) for p in matches if _is_recording(FsPath(p), format)]
            if not some:
                what = f"matches {len(matches)} paths but" if matches else "matches nothing:"
                raise InvalidInputError(f"{str(path)!r} {what} no recording; looked for "
                                        f"{_looked_for(format)}")
        elif len(paths) == 1:
            return None
        else:
            some = [path]
        found.update(dict.fromkeys(some))
    return list(found)


# -- all of them ------------------------------------------------------------------------------
def _outputs(folder, files: list[FsPath], suffix: str, option: str) -> list[str | None]:
    """Per recording, its output file in ``folder`` (created), or None without one."""
    from iem.errors import InvalidInputError

    if not folder:
        return [None] * len(files)
    folder = FsPath(folder)
    if folder.exists() and not folder.is_dir():
        raise InvalidInputError(f"{option} {folder}: with several recordings {option} is a "
                                f"folder (one {suffix} file per recording), and this is a file")
    out = [folder / f"{f.name}{suffix}" for f in files]
    if len(set(out)) < len(out):
        twins = sorted({str(f) for f, o in zip(files, out, strict=True) if out.count(o) > 1})
        raise InvalidInputError(f"{option} {folder}: recordings of the same name would write "
                                f"the same file ({', '.join(twins)}); give them distinct "
                                "names")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidInputError(f"{option} {folder}: cannot make the folder: "
                                f"{exc.strerror or exc}") from exc
    return [str(o) for o in out]


def run_many(args, files: list[FsPath]) -> list[dict]:
    """``iem replay`` of ``files``: each one's summary as it ends, then the table; the JSON
    (``--json``); every recording's entry, in order (the command exits 2 if one failed)."""
    import json
    from contextlib import closing

    from .core import write_output
    from .report import print_summary, print_table

    csvs = _outputs(args.out, files, ".csv", "--out")
    models = _outputs(args.save_model, files, ".msgpack", "--save-model")
    INPUTS.clear()  # read afresh: the files may have changed since this process last read
    inputs_of(args)  # a bad --truth, --model or --arm fails once, here
    n_jobs = min(args.jobs or 1, len(files))  # --jobs: 1 unless given
    print(f"replaying {len(files)} recordings, {n_jobs} at a time", file=sys.stderr,
          flush=True)
    tasks = [(args, str(f), c, m) for f, c, m in zip(files, csvs, models, strict=True)]
    entries: list[dict] = [{}] * len(tasks)
    start = time.perf_counter()
    with closing(_results(tasks, n_jobs)) as results:  # closed: the children stopped
        for k, entry in results:
            entries[k] = entry
            if entry["summary"] is not None:
                print_summary(entry["summary"])
            else:
                print(f"replay of {entry['file']} FAILED: {entry['error']}")
    wall = time.perf_counter() - start
    print_table(entries, wall, n_jobs)
    if args.json:
        write_output(args.json, json.dumps({"jobs": n_jobs, "wall_s": wall, "recordings": entries},
                                     indent=2, default=float) + "\n")
    return entries


def _results(tasks: list[tuple], n_jobs: int):
    """``(index, entry)`` of each task as it ends: in this process for one job, else in
    ``n_jobs`` child processes, all stopped on Ctrl-C (KeyboardInterrupt goes on up)."""
    if n_jobs == 1:
        for k, task in enumerate(tasks):
            yield k, replay_one(*task)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    pool = ProcessPoolExecutor(n_jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=child_init)
    try:
        futures = {pool.submit(replay_one, *task): k for k, task in enumerate(tasks)}
        for future in as_completed(futures):
            k = futures[future]
            try:
                yield k, future.result()
            except BrokenProcessPool as exc:  # a child died (killed, out of memory)
                yield k, {"file": tasks[k][1], "error": f"its replay process died ({exc})",
                          "final_phi": None, "summary": None}
    except BaseException:  # Ctrl-C, or the caller stopped: stop the children now
        _stop(pool)
        raise
    pool.shutdown()


def _stop(pool) -> None:
    """Cancel what has not started and terminate the children of ``pool``."""
    children = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for child in children:
        child.terminate()
    for child in children:
        child.join(5.0)
