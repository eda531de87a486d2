"""Every option of every ``iem`` command does something: each is read by the command's
``run`` (or by a function it hands its arguments to), and an option that would do nothing in
the case given is refused, naming it and why (:func:`deploy.options.refuse_unused`)."""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import sys
import textwrap
import types
from pathlib import Path

import pytest

from deploy.cli import COMMANDS, main

REPO = Path(__file__).resolve().parents[3]


# -- every option is read -------------------------------------------------------------------
def _imported(module) -> dict:
    """The names ``module`` binds, with those its functions import (``from X import f``)."""
    out = dict(vars(module))
    package = module.__name__.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(inspect.getsource(module))):
        if not isinstance(node, ast.ImportFrom):
            continue
        base = node.module or ""
        if node.level:
            root = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            base = f"{root}.{base}" if base else root
        for alias in node.names:
            source = importlib.import_module(base)
            out.setdefault(alias.asname or alias.name, getattr(source, alias.name, None))
    return out


def _repo_function(obj) -> bool:
    return isinstance(obj, types.FunctionType) and REPO in Path(inspect.getfile(obj)).parents


def reads_of(func, param: str = "args", seen: set | None = None) -> set[str]:
    """The attributes of the parameter ``param`` that ``func`` reads (``param.x``,
    ``getattr(param, "x")``), and those of the repository's functions it hands ``param`` to
    (directly, or as the argument of a function it hands on: ``pool.submit(f, param)``)."""
    seen = set() if seen is None else seen
    if (func, param) in seen:
        return set()
    seen.add((func, param))
    names = _imported(sys.modules[func.__module__])
    out = set()

    def is_param(node) -> bool:
        return isinstance(node, ast.Name) and node.id == param

    for node in ast.walk(ast.parse(textwrap.dedent(inspect.getsource(func)))):
        if isinstance(node, ast.Attribute) and is_param(node.value):
            out.add(node.attr)
        if not isinstance(node, ast.Call):
            continue
        if getattr(node.func, "id", None) == "getattr" and is_param(node.args[0]) \
                and isinstance(node.args[1], ast.Constant):
            out.add(node.args[1].value)
        at = [i for i, a in enumerate(node.args) if is_param(a)]
        callee = names.get(getattr(node.func, "id", None) or getattr(node.func, "attr", None))
        handed = [(callee, i) for i in at]
        for k, a in enumerate(node.args):
            handed += [(names.get(getattr(a, "id", None)), i - k - 1) for i in at if i > k]
        for target, position in handed:
            if _repo_function(target):
                params = list(inspect.signature(target).parameters)
                if position < len(params):
                    out |= reads_of(target, params[position], seen)
    return out


def unread_options(configure, run) -> set[str]:
    """The options ``configure`` defines that ``run`` never reads."""
    parser = argparse.ArgumentParser()
    configure(parser)
    return {a.option_strings[0] if a.option_strings else a.dest
            for a in parser._actions if a.dest != "help" and a.dest not in reads_of(run)}


def _commands(prefix: str, table: dict):
    for name, (target, _) in table.items():
        if isinstance(target, dict):
            yield from _commands(f"{prefix}{name} ", target)
        else:
            yield f"{prefix}{name}", target


ALL = dict(_commands("", COMMANDS))


@pytest.mark.parametrize("command", sorted(ALL))
def test_every_option_of_a_command_is_read_by_its_run(command):
    module = importlib.import_module(ALL[command])
    assert unread_options(module.configure, module.run) == set()


def _configure(parser):
    parser.add_argument("--used")
    parser.add_argument("--handed-on")
    parser.add_argument("--in-a-worker")
    parser.add_argument("--ignored")
    parser.add_argument("files", nargs="*")


def _helper(options):
    return options.handed_on


def _worker(options, n):
    return getattr(options, "in_a_worker", None), n


def _run(args):
    import concurrent.futures

    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        pool.submit(_worker, args, 1)
    return args.used, _helper(args), args.files


def test_the_check_sees_an_option_no_run_reads():
    """The test above can fail: an option read nowhere is found; read directly, by a helper
    or by a worker it is handed to, it is not."""
    assert unread_options(_configure, _run) == {"--ignored"}


# -- an option that does nothing here is refused --------------------------------------------
REFUSED = [
    # (command line, what the message names)
    # (a short --duration: were the option taken, the controller would stop by itself)
    (["sim-controller", "--interface", "slcan-pty", "--channel", "/dev/ttyACM0",
      "--duration", "0.2"],
     ["--channel has no effect", "--interface slcan-pty", "new pty"]),
    (["sim-controller", "--interface", "serial-pty", "--profile", "classic",
      "--duration", "0.2"],
     ["--profile has no effect", "--interface serial-pty", "msgpack"]),
    (["sim-controller", "--interface", "virtual", "--delay-cycles", "5", "--duration", "0.2"],
     ["--delay-cycles has no effect without --delay"]),
    (["sim-controller", "--interface", "virtual", "--silence", "1:1", "--fault-seed", "3",
      "--duration", "0.2"],
     ["--fault-seed has no effect without --drop, --corrupt, --duplicate or --delay"]),
    (["train", "--out", "m.msgpack", "--kind", "IEM", "--noise", "sensor", "--rate", "500"],
     ["--rate and --noise have no effect with --kind IEM", "only IEM+phys"]),
    (["train", "--out", "m.msgpack", "--arm-flange", "panda_hand"],
     ["--arm-flange panda_hand", "'panda'", "'panda_link8'", "URDF file"]),
    (["calibrate", "--write-motion", "m.csv", "--out", "a.arm", "--rate", "200"],
     ["--out and --rate have no effect with --write-motion"]),
    (["calibrate", "bare.csv", "--out", "a.arm", "--channel", "can0"],
     ["--channel has no effect without --interface"]),
    (["calibrate", "--interface", "virtual", "--duration", "1", "--out", "a.arm",
      "--topic", "/joint_states"], ["--topic has no effect without a REC"]),
    (["identify", "--loaded", "l.csv", "--bare", "b.csv", "--out", "p.toml",
      "--end-effector", "none"], ["--end-effector has no effect with --bare"]),
    (["replay", "one.csv", "--jobs", "2"], ["--jobs has no effect with one recording"]),
    (["bench", "longrun", "--routing-only", "--minutes", "1", "--plain"],
     ["--minutes and --plain have no effect with --routing-only"]),
    (["bench", "longrun", "--plain", "--budget", "50"],
     ["--budget has no effect with --plain"]),
    (["bench", "writeback", "--scenarios", "tool_removed", "--real", "rec"],
     ["--real has no effect without the real scenario"]),
    (["bench", "writeback", "--scenarios", "real", "--plant", "ideal"],
     ["--plant has no effect with the real scenario alone"]),
]


@pytest.mark.parametrize(("argv", "names"), REFUSED, ids=lambda v: " ".join(v)[:60])
def test_an_option_that_would_do_nothing_is_refused(argv, names, tmp_path, monkeypatch,
                                                    capsys):
    monkeypatch.chdir(tmp_path)  # nothing the command might write lands in the checkout
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("iem: error: ") and err.count("\n") == 1, err
    for name in names:
        assert name in err, (name, err)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["train", "calibrate", "identify", "sim-controller",
                                     "bench sim", "bench paper", "bench realistic",
                                     "bench custom", "bench longrun", "bench real"])
def test_a_command_without_a_gate_takes_no_rated_mass(command, capsys):
    """``--rated-mass-kg`` is the gate's: the commands that run no gate do not offer it."""
    with pytest.raises(SystemExit) as exit_:
        main([*command.split(), "--help"])
    assert exit_.value.code == 0 and "--arm-model" in (out := capsys.readouterr().out)
    assert "--rated-mass-kg" not in out
