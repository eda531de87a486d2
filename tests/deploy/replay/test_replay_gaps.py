"""Issue 10: a clean recording replayed with 5 % of its joint-state frames removed estimates
as well as the whole recording (before the gap rule: 0.0001 -> 0.27 kg), with python-can's
own reader and writer making the lossy copy."""

from __future__ import annotations

import can
import numpy as np
import pytest

from deploy.replay.core import replay
from firmware_bridge.protocol import profile as get_profile
from sim.family import default_test_payload
from sim.paths import excitation_path

from .test_replay import record_sim


def _thin(src, dst, fraction: float, seed: int) -> int:
    """Copy ``src`` to ``dst`` without ``fraction`` of its joint-state frames."""
    rng = np.random.default_rng(seed)
    js = get_profile("fd").joint_state.parts[0].frame_id
    removed = 0
    writer = can.Logger(str(dst))
    try:
        for msg in can.LogReader(str(src)):
            if msg.arbitration_id == js and rng.random() < fraction:
                removed += 1
                continue
            writer.on_message_received(msg)
    finally:
        writer.stop()
    return removed


@pytest.fixture(scope="module")
def phys_model(trained_phys_model_file):
    """The session's light IEM+phys (tests/conftest.py), this module's copy."""
    from iem.persistence import load_model

    return load_model(trained_phys_model_file)


def test_a_recording_with_lost_frames_estimates_as_well_as_the_whole(tmp_path, phys_model):
    whole, thinned = tmp_path / "whole.blf", tmp_path / "thinned.blf"
    record_sim(whole, "fd", path=excitation_path().slice(0, 6.0), seed=3)
    removed = _thin(whole, thinned, 0.05, seed=8)
    truth = default_test_payload()
    clean, _ = replay(whole, model=phys_model, truth=truth, log=lambda _: None)
    lossy, _ = replay(thinned, model=phys_model, truth=truth, log=lambda _: None)
    assert removed > 200 and lossy["frames"]["lost"] == removed
    m_clean, m_lossy = clean["mae_groups"]["mass"], lossy["mae_groups"]["mass"]
    assert m_lossy <= max(1.5 * m_clean, m_clean + 0.001), (m_clean, m_lossy)
    for g in ("com", "inertia"):
        assert lossy["mae_groups"][g] <= 1.5 * clean["mae_groups"][g] + 1e-4, g
