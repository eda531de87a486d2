"""A cell's configuration built in code (:func:`deploy.config.cell_config`): the arm model
and its rating give ``[arm]`` and ``[gate]``, the caller's sections join them, and the whole
is checked as a ``cell.toml`` is."""

from __future__ import annotations

import pytest

from deploy.config import ConfigError, cell_config, cell_sections
from iem.errors import InvalidInputError
from sim.description import arm_description


def test_the_arm_model_gives_the_arm_and_the_rating():
    fr3 = arm_description("fr3")
    cfg = cell_config(fr3, where="test")
    assert (cfg.arm.model, cfg.arm.flange) == ("fr3", "fr3_link8")
    assert cfg.gate.rated_mass_kg == fr3.rated_payload_kg == 3.0
    assert cell_config(fr3, 2.5, where="test").gate.rated_mass_kg == 2.5
    assert cell_config(where="test").arm.description().name == "panda"  # the default


def test_an_arm_model_from_a_file_needs_a_rating(tmp_path):
    fr3 = arm_description("fr3")
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(fr3.text, encoding="utf-8")
    own = arm_description(str(urdf), fr3.flange)
    with pytest.raises(InvalidInputError, match=r"gives no rated payload.*--rated-mass-kg KG"):
        cell_sections(own)
    cfg = cell_config(own, 2.5, where="test")
    assert (cfg.arm.model, cfg.arm.flange, cfg.gate.rated_mass_kg) == (str(urdf), "fr3_link8",
                                                                       2.5)


def test_the_callers_sections_join_the_arm_and_gate():
    cfg = cell_config(arm_description("panda"), where="test", status=True,
                      link={"kind": "virtual", "channel": "c", "profile": "classic"},
                      model={"path": "m.msgpack", "seed": 3}, arm={"noise": "sensor"},
                      gate={"max_rate_hz": 0.5}, host={"cpu_dma_latency_us": 10},
                      estimate={"block_frames": 5})
    assert (cfg.link.channel, cfg.link.profile, cfg.model.seed) == ("c", "classic", 3)
    assert (cfg.arm.model, cfg.arm.noise) == ("panda", "sensor")
    assert (cfg.gate.max_rate_hz, cfg.gate.rated_mass_kg) == (0.5, 3.0)
    assert cfg.log.status_line == "on" and cell_config(where="t").log.status_line == "off"
    assert (cfg.host.cpu_dma_latency_us, cfg.estimate.block_frames) == (10, 5)


@pytest.mark.parametrize(("kind", "allowed"), [("IEM", True), ("IEM+phys", False), (None, False)])
def test_the_papers_iem_writes_without_an_uncertainty(kind, allowed):
    """The paper's IEM reports no uncertainty: a cell built for it lets its gate write."""
    model = {"path": "m.msgpack"} if kind is None else {"path": "m.msgpack", "kind": kind}
    assert cell_config(where="test", model=model).gate.allow_without_uncertainty is allowed


def test_what_a_cell_toml_may_not_hold_is_refused_naming_the_cell():
    with pytest.raises(ConfigError, match=r"bench x: unknown key\(s\) \['bogus'\] in \[host\]"):
        cell_config(where="bench x", host={"bogus": 1})
    with pytest.raises(ConfigError, match=r"bench x: \[arm\] end_effector weighs"):
        cell_config(arm_description("panda"), 0.5, where="bench x")
