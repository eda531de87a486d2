"""One implementation per algorithm (issues 29 and 31): at 100 Hz block points the compiled
numba twins of the per-sample numerics saved under 0.01 of a core and cost about 100 MB, so
they went; nothing may bring back a second implementation chosen per call."""

from tests.test_layers import REPO, imported


def test_no_compiled_twins():
    sources = [p for pkg in ("iem", "deploy", "sim", "firmware_bridge")
               for p in (REPO / pkg).rglob("*.py")]
    assert sources
    assert not [p for p in sources if "numba" in imported(p)]
    assert not [p for p in sources if p.stem == "kernels"]
    assert not [p for p in sources if "IEM_KERNELS" in p.read_text(encoding="utf-8")]
    assert "numba" not in (REPO / "pyproject.toml").read_text(encoding="utf-8")
