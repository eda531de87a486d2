"""The layers point one way: an import test over the packages' source (ast, every import,
function-level ones included).

The rules: the value types and errors (``iem.types``, ``iem.payload``, ``iem.errors``) are
the numpy-only home everything imports; ``iem`` imports neither ``sim`` nor ``deploy``;
``firmware_bridge`` and the safety gate (``deploy/gate*.py``) never import ``sim``; ``sim``
imports neither ``deploy`` nor ``firmware_bridge``. So a definition every layer shares (the
model kind's default, :data:`iem.model_kinds.DEFAULT_MODEL`) lives in the lowest layer that
needs it.
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


def test_no_arrow_points_the_wrong_way():
    found = {f: sorted(b) for f, b in wrong_arrows().items()}
    assert not found, f"imports against the layers (see this test's docstring): {found}"


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
