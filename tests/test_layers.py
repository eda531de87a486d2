"""The layers point one way: an import test over the packages' source (ast, every import,
function-level ones included).

The rules (issue 29): the value types and errors (``iem.types``, ``iem.payload``,
``iem.errors``) are the numpy-only home everything imports; ``iem`` imports neither ``sim``
nor ``deploy``; ``firmware_bridge`` and the safety gate (``deploy/gate*.py``) never import
``sim``; ``sim`` imports neither ``deploy`` nor ``firmware_bridge``. An arrow that must
point the wrong way for a while is listed in :data:`KNOWN` (none is): a new wrong arrow
fails, and so does a listed one that is gone (shrink the list).
"""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("iem", "sim", "deploy", "firmware_bridge")

FORBIDDEN = {
    "iem": ("sim", "deploy", "firmware_bridge"),
    "sim": ("deploy", "firmware_bridge"),
    "firmware_bridge": ("sim", "deploy"),
    "deploy/gate": ("sim",),
}

KNOWN: dict[str, set[str]] = {}


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
    if rel.startswith("deploy/gate"):
        return FORBIDDEN["deploy/gate"]
    return FORBIDDEN.get(rel.split("/")[0], ())


def wrong_arrows() -> dict[str, set[str]]:
    out = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            bad = _imports(path) & set(_rules(rel))
            if bad:
                out[rel] = bad
    return out


def test_no_new_arrow_points_the_wrong_way():
    found = wrong_arrows()
    new = {f: sorted(b - KNOWN.get(f, set())) for f, b in found.items()
           if b - KNOWN.get(f, set())}
    assert not new, f"imports against the layers (see this test's docstring): {new}"


def gone_arrows(known: dict[str, set[str]], found: dict[str, set[str]]) -> dict[str, list]:
    """The arrows listed in ``known`` that ``found`` no longer holds."""
    return {f: sorted(b - found.get(f, set())) for f, b in known.items()
            if b - found.get(f, set())}


def test_the_known_wrong_arrows_are_still_there():
    """A listed arrow that is gone: take it off the list, so it cannot come back unseen."""
    gone = gone_arrows(KNOWN, wrong_arrows())
    assert not gone, f"remove from KNOWN: {gone}"


def test_a_listed_arrow_that_is_gone_is_seen():
    """The test above can fail: the arrows the list once held (commissioning's numerics in
    iem, the simulated controller and ROS 2 peer in the bridge, all importing sim) are
    reported gone."""
    once = {"iem/identify.py": {"sim"}, "firmware_bridge/sim_controller.py": {"sim"},
            "firmware_bridge/ros2_peers.py": {"sim"}}
    assert gone_arrows(once, wrong_arrows()) == {f: ["sim"] for f in once}


def test_the_value_types_home_is_numpy_only():
    for name in ("types", "payload", "errors", "physics/torque_noise"):
        imported = _imports(REPO / "iem" / f"{name}.py")
        assert not imported - {"iem"}, (name, imported)
        text = (REPO / "iem" / f"{name}.py").read_text(encoding="utf-8")
        assert "import pinocchio" not in text and "import mujoco" not in text


def test_the_rule_sees_a_wrong_arrow(tmp_path, monkeypatch):
    """The test can fail: a gate module importing sim is found."""
    import tests.test_layers as layers

    fake = tmp_path / "deploy"
    fake.mkdir()
    (fake / "gate_extra.py").write_text("def f():\n    from sim.payload import Payload\n")
    for package in ("iem", "sim", "firmware_bridge"):
        (tmp_path / package).mkdir()
    monkeypatch.setattr(layers, "REPO", tmp_path)
    assert layers.wrong_arrows() == {"deploy/gate_extra.py": {"sim"}}
