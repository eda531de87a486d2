"""One of each: the model kind a cell runs unless told otherwise is defined once,
:data:`iem.model_kinds.DEFAULT_MODEL`, and every default of a kind (the configuration's,
``iem train``'s, ``iem replay``'s fresh model, the trainer's) is that constant, imported.

The source check reads every module of the packages (ast) for a model kind written as a
default: a parameter's default, a ``default=`` keyword, a class field's default, a module
constant, or the fallback of ``or`` and of ``x if c else y``.

A cell's configuration made in code (the demo, a replay, the benchmarks) has one builder,
:func:`deploy.config.cell_config`: no other module makes a configuration of a dict. A
declared end effector has one resolution, :func:`sim.end_effector.end_effector_of`."""

import ast
import inspect
from pathlib import Path

from tests.test_layers import PACKAGES, REPO

THE_DEFINITION = ("iem/model_kinds.py", "DEFAULT_MODEL")


def _kind(node, kinds) -> bool:
    return isinstance(node, ast.Constant) and node.value in kinds


def kind_defaults(root: Path, kinds) -> list[tuple[str, int, str]]:
    """``(file, line, what)`` of every model kind of ``kinds`` written as a default in the
    packages under ``root``."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in tree.body:  # module constants
                if isinstance(node, ast.Assign | ast.AnnAssign) and _kind(node.value, kinds):
                    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                    for target in targets:
                        name = getattr(target, "id", "")
                        if (rel, name) != THE_DEFINITION:
                            found.append((rel, node.lineno, f"constant {name}"))
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                    for d in [*node.args.defaults, *node.args.kw_defaults]:
                        if _kind(d, kinds):
                            found.append((rel, d.lineno, "parameter default"))
                elif isinstance(node, ast.Call):
                    for k in node.keywords:
                        if k.arg == "default" and _kind(k.value, kinds):
                            found.append((rel, k.value.lineno, "default= keyword"))
                elif isinstance(node, ast.ClassDef):
                    for stmt in node.body:  # a dataclass field's default
                        if isinstance(stmt, ast.AnnAssign) and _kind(stmt.value, kinds):
                            found.append((rel, stmt.lineno, "field default"))
                elif isinstance(node, ast.BoolOp):
                    if isinstance(node.op, ast.Or) and _kind(node.values[-1], kinds):
                        found.append((rel, node.lineno, "'or' fallback"))
                elif isinstance(node, ast.IfExp) and (_kind(node.body, kinds)
                                                      or _kind(node.orelse, kinds)):
                    found.append((rel, node.lineno, "conditional fallback"))
    return found


def _kinds():
    from iem.model_kinds import MODELS

    return set(MODELS)


def test_the_model_kind_default_is_written_once():
    assert kind_defaults(REPO, _kinds()) == []


def test_the_check_sees_a_second_default(tmp_path):
    """The test above can fail: each way of writing a second default is found."""
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "iem" / "model_kinds.py").write_text('DEFAULT_MODEL = "IEM+phys"\n')
    (tmp_path / "deploy" / "more.py").write_text(
        'from dataclasses import dataclass\n'
        'DEFAULT_KIND = "IEM"\n'
        'def train(kind="IEM"):\n    return kind or "IEM+phys"\n'
        'def pick(ok):\n    return "IEM+phys" if ok else "IEM"\n'
        '@dataclass\nclass C:\n    kind: str = "IEM+phys"\n'
        'def configure(p):\n    p.add_argument("--kind", default="IEM")\n')
    assert sorted(kind_defaults(tmp_path, _kinds())) == [
        ("deploy/more.py", 2, "constant DEFAULT_KIND"), ("deploy/more.py", 3, "parameter default"),
        ("deploy/more.py", 4, "'or' fallback"), ("deploy/more.py", 6, "conditional fallback"),
        ("deploy/more.py", 9, "field default"), ("deploy/more.py", 11, "default= keyword")]


class _Trained(Exception):
    """What the replay asked the trainer for."""


def test_every_default_of_a_kind_is_the_one_constant(tmp_path, monkeypatch):
    import argparse

    import deploy.commands.train
    import deploy.model.training
    from deploy.config import MODEL_KINDS, ModelConfig
    from deploy.replay.core import replay
    from iem.model_kinds import DEFAULT_MODEL, new_model

    assert DEFAULT_MODEL in MODEL_KINDS
    assert ModelConfig().kind == DEFAULT_MODEL
    for function in (deploy.model.training.train_initial_model, new_model):
        assert inspect.signature(function).parameters["kind"].default == DEFAULT_MODEL
    parser = argparse.ArgumentParser()
    deploy.commands.train.configure(parser)
    assert parser.parse_args(["--out", "m.msgpack"]).kind == DEFAULT_MODEL  # iem train

    def trainer(kind, *args, **kwargs):
        raise _Trained(kind, kwargs["rate_hz"], kwargs["block_frames"])

    monkeypatch.setattr(deploy.model.training, "train_initial_model", trainer)
    csv = tmp_path / "rec.csv"
    header = ["t", *(f"{n}{j}" for n in ("q", "dq", "tau") for j in range(1, 8))]
    rows = [",".join([f"{k * 1e-3:.3f}", *["0.1"] * 21]) for k in range(20)]
    csv.write_text("\n".join([",".join(header), *rows]) + "\n", encoding="utf-8")
    try:
        replay(csv, log=lambda *a: None, block_frames=5)  # iem replay without --model
    except _Trained as asked:
        assert asked.args == (DEFAULT_MODEL, 1000.0, 5)  # at the recording's point rate
    else:
        raise AssertionError("the replay trained no fresh model")


# -- a cell's configuration built in code: one builder ----------------------------------------
THE_BUILDER = "deploy/config/"
"""Where a configuration is made from a dict: :func:`deploy.config.cell_config` (a cell
built in code) over :func:`deploy.config.config_from_dict` (a parsed file)."""


def config_dicts(root: Path) -> list[tuple[str, int]]:
    """``(file, line)`` of every call of ``config_from_dict`` in the packages under ``root``
    outside :data:`THE_BUILDER`: a cell's sections written out again."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel.startswith(THE_BUILDER):
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Call) and "config_from_dict" in (
                        getattr(node.func, "id", None), getattr(node.func, "attr", None)):
                    found.append((rel, node.lineno))
    return found


def test_a_cell_configuration_in_code_has_one_builder():
    assert config_dicts(REPO) == []


def test_the_check_sees_a_second_builder(tmp_path):
    """The test above can fail: a dict made a configuration elsewhere is found."""
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "deploy" / "config").mkdir()
    (tmp_path / "deploy" / "config" / "build.py").write_text("config_from_dict({})\n")
    (tmp_path / "deploy" / "bench.py").write_text(
        "import deploy.config\nfrom deploy.config import config_from_dict\n"
        "config_from_dict({'arm': {}})\ndeploy.config.config_from_dict({})\n")
    assert config_dicts(tmp_path) == [("deploy/bench.py", 3), ("deploy/bench.py", 4)]


# -- an end effector: one resolution ----------------------------------------------------------
THE_RESOLUTION = ("sim/description.py", "sim/end_effector.py")
"""Where a declared end effector is resolved: ``ArmDescription.end_effector_spec`` (None and ""
the arm model's default) and :func:`sim.end_effector.end_effector_of` (an ``EndEffector`` as
it is)."""


def end_effector_resolutions(root: Path) -> list[tuple[str, int, str]]:
    """``(file, line, what)`` of every end-effector resolution written out in the packages
    under ``root`` outside :data:`THE_RESOLUTION`: a fallback ``x or d.default_end_effector``,
    or an ``isinstance(x, EndEffector)``."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel in THE_RESOLUTION:
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or) and \
                        getattr(node.values[-1], "attr", None) == "default_end_effector":
                    found.append((rel, node.lineno, "default fallback"))
                elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == \
                        "isinstance" and getattr(node.args[1], "id", None) == "EndEffector":
                    found.append((rel, node.lineno, "isinstance"))
    return found


def test_an_end_effector_is_resolved_in_one_place():
    assert end_effector_resolutions(REPO) == []


def test_the_check_sees_a_second_resolution(tmp_path):
    """The test above can fail: each way of resolving one again is found."""
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "sim" / "description.py").write_text("s = ee or self.default_end_effector\n")
    (tmp_path / "sim" / "plant.py").write_text(
        "from sim.end_effector import EndEffector, end_effector\n"
        "ee = x if isinstance(x, EndEffector) else end_effector(x or d.default_end_effector)\n")
    assert sorted(end_effector_resolutions(tmp_path)) == [
        ("sim/plant.py", 2, "default fallback"), ("sim/plant.py", 2, "isinstance")]
