"""The layers point one way: an import test over the packages' source (ast, every import,
function-level ones included).

The rules: the value types and errors (``iem.types``, ``iem.payload``, ``iem.errors``) are
the numpy-only home everything imports; ``iem`` imports neither ``sim`` nor ``deploy``;
``firmware_bridge`` and the write-back (``deploy/writeback/``: the safety gate and all it is
made of) never import ``sim``; ``sim`` imports neither ``deploy`` nor ``firmware_bridge``. So a
definition every layer shares (the model kind's default,
:data:`iem.model_kinds.DEFAULT_MODEL`) lives in the lowest layer that needs it.

Inside ``deploy``, the rooms (its sub-packages, and ``options.py`` and ``cli.py``) stand on
the floors of :data:`FLOORS` and import only rooms on lower floors: ``deploy/writeback/``
imports nothing of ``deploy`` outside itself; and no module of the repository imports itself
back through others (no import circle).
"""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("iem", "sim", "deploy", "firmware_bridge")

FORBIDDEN = {
    "iem": ("sim", "deploy", "firmware_bridge"),
    "sim": ("deploy", "firmware_bridge"),
    "firmware_bridge": ("sim", "deploy"),
    "deploy/writeback": ("sim",),
}

FLOORS = (
    ("options",),
    ("writeback",),
    ("config",),
    ("model",),
    ("service",),
    ("replay",),
    ("simcell",),
    ("cli",),
    ("commands", "bench"),
)
"""The rooms of ``deploy`` from the ground floor up; a room imports only rooms on lower
floors (and itself). ``options`` (argument builders) imports nothing of ``deploy``: the
commands, the benches, a replay's job and the simulated ROS 2 controller share it. The
write-back is below the configuration, which reads the gate's settings and ranges; the model
is set up from the configuration; the service runs the model; a replay runs the service, and
the simulated cell runs it beside the simulated controller. ``cli`` imports only the
configuration's error (the exit status of ``iem run``): it loads the commands and benches by
name, and commands take their exit statuses from it. Commands and benches stand side by side
and import neither each other."""


def imported(path: Path) -> set[str]:
    """The top-level modules a source file imports (every import, function-level ones too;
    relative ones left out)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


def _imports(path: Path) -> set[str]:
    return imported(path) & set(PACKAGES)


def _rules(rel: str) -> tuple[str, ...]:
    if rel.startswith("deploy/writeback/"):
        return FORBIDDEN["deploy/writeback"]
    return FORBIDDEN.get(rel.split("/")[0], ())


def _sources():
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            yield path.relative_to(REPO).as_posix(), path


def wrong_arrows() -> dict[str, set[str]]:
    out = {}
    for rel, path in _sources():
        bad = _imports(path) & set(_rules(rel))
        if bad:
            out[rel] = bad
    return out


def module_of(rel: str) -> tuple[str, bool]:
    """``(dotted name, is a package)`` of the source file ``rel``."""
    parts = rel[:-len(".py")].split("/")
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), True
    return ".".join(parts), False


def imported_modules(rel: str, path: Path) -> set[str]:
    """The modules of the repository's packages that the source file ``rel`` imports (every
    import, function-level ones too, relative ones resolved): ``from a.b import c`` imports
    the module ``a.b.c`` where there is one, else ``a.b``."""
    name, is_package = module_of(rel)
    package = name.split(".") if is_package else name.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                sub_rel = sub.replace(".", "/")
                known = (REPO / f"{sub_rel}.py").exists() or (REPO / sub_rel /
                                                              "__init__.py").exists()
                out.add(sub if known else module)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return {m for m in out if m.split(".")[0] in PACKAGES} - {name}


def room_of(module: str) -> str | None:
    """The room of ``deploy`` a module stands in (``deploy.service.loop`` -> ``service``,
    ``deploy.cli`` -> ``cli``); None for ``deploy`` itself and modules of other packages."""
    parts = module.split(".")
    return parts[1] if parts[0] == "deploy" and len(parts) > 1 else None


def floor_of(room: str) -> int:
    for k, rooms in enumerate(FLOORS):
        if room in rooms:
            return k
    raise AssertionError(f"deploy/{room} stands on no floor of FLOORS: add it there")


def arrows_up() -> dict[str, set[str]]:
    """Per source file of ``deploy``, the rooms it imports that stand on its own floor or
    higher (other than its own room)."""
    out = {}
    for rel, path in _sources():
        room = room_of(module_of(rel)[0])
        if room is None:
            continue
        bad = {other for m in imported_modules(rel, path)
               if (other := room_of(m)) is not None and other != room
               and floor_of(other) >= floor_of(room)}
        if bad:
            out[rel] = bad
    return out


def writeback_escapes() -> dict[str, set[str]]:
    """Per source file of ``deploy/writeback/``, the modules of ``deploy`` outside it that it
    imports."""
    out = {}
    for rel, path in _sources():
        if rel.startswith("deploy/writeback/"):
            bad = {m for m in imported_modules(rel, path)
                   if m.split(".")[0] == "deploy" and room_of(m) != "writeback"}
            if bad:
                out[rel] = bad
    return out


def import_circles() -> list[list[str]]:
    """The sets of the repository's modules that import each other in a loop (strongly
    connected components of more than one module; a package is its ``__init__``)."""
    graph = {module_of(rel)[0]: imported_modules(rel, path) for rel, path in _sources()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                circles.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(circles)


def test_no_arrow_points_the_wrong_way():
    found = {f: sorted(b) for f, b in wrong_arrows().items()}
    assert not found, f"imports against the layers (see this test's docstring): {found}"


def test_the_writeback_imports_nothing_of_deploy_outside_itself():
    found = {f: sorted(b) for f, b in writeback_escapes().items()}
    assert not found, f"deploy/writeback/ imports these of deploy: {found}"


def test_the_rooms_of_deploy_import_only_downward():
    found = {f: sorted(b) for f, b in arrows_up().items()}
    assert not found, f"imports of a room on the same floor or higher (FLOORS): {found}"


def test_no_module_imports_itself_back():
    assert import_circles() == []


def test_the_value_types_home_is_numpy_only():
    for name in ("types", "payload", "errors", "physics/torque_noise"):
        imported = _imports(REPO / "iem" / f"{name}.py")
        assert not imported - {"iem"}, (name, imported)
        text = (REPO / "iem" / f"{name}.py").read_text(encoding="utf-8")
        assert "import pinocchio" not in text and "import mujoco" not in text


def _tree(tmp_path, files: dict[str, str]):
    for package in PACKAGES:
        (tmp_path / package).mkdir(exist_ok=True)
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_rule_sees_a_wrong_arrow(tmp_path, monkeypatch):
    """The test can fail: a write-back module importing sim is found."""
    import tests.test_layers as layers

    _tree(tmp_path, {"deploy/writeback/extra.py":
                     "def f():\n    from sim.payload import Payload\n"})
    monkeypatch.setattr(layers, "REPO", tmp_path)
    assert layers.wrong_arrows() == {"deploy/writeback/extra.py": {"sim"}}


def test_the_rule_sees_the_writeback_import_deploy(tmp_path, monkeypatch):
    """The test can fail: a write-back module importing the configuration, by an absolute or
    a relative import, is found; one importing its own room is not."""
    import tests.test_layers as layers

    _tree(tmp_path, {"deploy/writeback/gate.py": "from .settings import GateConfig\n",
                     "deploy/writeback/settings.py": "GateConfig = 1\n",
                     "deploy/writeback/extra.py":
                     "def f():\n    from deploy.config import ConfigError\n",
                     "deploy/writeback/more.py": "from ..config import load\n",
                     "deploy/config/load.py": "X = 1\n"})
    monkeypatch.setattr(layers, "REPO", tmp_path)
    assert layers.writeback_escapes() == {"deploy/writeback/extra.py": {"deploy.config"},
                                          "deploy/writeback/more.py": {"deploy.config.load"}}


def test_the_rule_sees_a_room_import_upward(tmp_path, monkeypatch):
    """The test can fail: a room importing a higher one, or one on its own floor, is found;
    one importing a lower room is not; a room on no floor is named."""
    import pytest

    import tests.test_layers as layers

    _tree(tmp_path, {"deploy/config/load.py": "from deploy.service.loop import Service\n",
                     "deploy/service/loop.py": "from deploy.config import load\n",
                     "deploy/commands/demo.py": "from deploy.bench import e2e\n",
                     "deploy/bench/e2e.py": "X = 1\n",
                     "deploy/cli.py": "from deploy.commands import demo\n"})
    monkeypatch.setattr(layers, "REPO", tmp_path)
    assert layers.arrows_up() == {"deploy/config/load.py": {"service"},
                                  "deploy/commands/demo.py": {"bench"},
                                  "deploy/cli.py": {"commands"}}
    (tmp_path / "deploy" / "attic").mkdir()
    (tmp_path / "deploy" / "attic" / "old.py").write_text("from deploy.cli import main\n")
    with pytest.raises(AssertionError, match="deploy/attic stands on no floor"):
        layers.arrows_up()


def test_the_rule_sees_an_import_circle(tmp_path, monkeypatch):
    """The test can fail: two modules that import each other, one of them in a function,
    are a circle; a package's ``__init__`` handing on its modules' names is not."""
    import tests.test_layers as layers

    _tree(tmp_path, {"sim/robot.py": "from .end_effector import EndEffector\n",
                     "sim/end_effector.py": "def f():\n    from .robot import ArmModel\n",
                     "deploy/config/__init__.py": "from .load import load_config\n",
                     "deploy/config/load.py": "from .sections import ConfigError\n",
                     "deploy/config/sections.py": "ConfigError = ValueError\n"})
    monkeypatch.setattr(layers, "REPO", tmp_path)
    assert layers.import_circles() == [["sim.end_effector", "sim.robot"]]
