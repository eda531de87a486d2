"""Block points (iem.signals.blocks): the means of consecutive gap-free frames, against numpy on
recorded frames with gaps, one frame at a time against a chunk at once, and the online loop
fed frames against the same loop fed the blocks."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_bridge.errors import EndOfStream
from firmware_bridge.recordings import open_recording
from iem.errors import InvalidInputError
from iem.online import OnlineIdentifier
from iem.physics import PhysicsInformedEnsemble
from iem.signals.blocks import BlockFormer
from iem.types import JointState


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """2 s of the simulated Panda written as a CAN log and read back through the replay
    link, with three gaps cut out of it (1, 3 and 50 lost frames: two bridged by the gap
    rule, one a restart) and one frame repeated (not newer)."""
    from sim.family import default_test_payload
    from sim.paths import excitation_path
    from sim.plant import ArmPlant
    from tests.deploy.commands.test_identify import write_log

    path = tmp_path_factory.mktemp("blocks") / "rec.blf"
    rollout = ArmPlant(payload=default_test_payload(), seed=3).follow(
        excitation_path(2.0, seed=1, period=2.0))
    write_log(rollout, path)
    link = open_recording(path)
    frames = []
    try:
        while True:
            frames.append(link.read(0.1))
    except EndOfStream:
        pass
    finally:
        link.close()
    T = np.array([f.t for f in frames])
    X = np.array([np.concatenate((f.q, f.dq, f.tau_J)) for f in frames])
    keep = np.ones(len(T), dtype=bool)
    keep[[105]] = False  # 1 lost
    keep[507:510] = False  # 3 lost
    keep[1205:1255] = False  # 50 lost: longer than the 20 ms bridged, a restart
    idx = np.flatnonzero(keep)
    idx = np.insert(idx, 800, idx[799])  # a duplicate
    return T[idx], X[idx], idx


def _expected(T, X, size=10, rate=1000.0, bridge=20):
    """Blocks by a plain reading of the rule: frames not newer dropped, up to ``bridge`` lost
    frames interpolated, a longer gap closing the block; rows as ``(t, x, received)``."""
    blocks, current, last = [], [], None

    def add(row):
        current.append(row)
        if len(current) == size:
            blocks.append(list(current))
            current.clear()

    for i, (t, x) in enumerate(zip(T, X, strict=True)):
        k = None if last is None else round((t - last[0]) * rate)
        if k is None or abs(k) > bridge:
            if current:
                blocks.append(list(current))
                current.clear()
        elif k <= 0:
            continue
        else:
            for j in range(1, k):
                add((last[0] + (t - last[0]) * j / k, last[1] + (x - last[1]) * j / k, None))
        add((t, x, i))
        last = (t, x)
    return blocks


def test_block_means_are_numpy_means_and_bridge_lost_frames(recorded):
    T, X, _ = recorded
    former = BlockFormer(10, 1000.0)
    blocks = former.push_many(T, X)
    expected = _expected(T, X)
    assert len(blocks) == len(expected)
    for k, rows in enumerate(expected):
        np.testing.assert_allclose(blocks.X[k], np.mean([r[1] for r in rows], axis=0),
                                   rtol=0, atol=1e-12)
        assert blocks.t[k] == pytest.approx(np.mean([r[0] for r in rows]), abs=1e-12)
        assert blocks.frames[k] == len(rows)
        assert blocks.last[k] == max(r[2] for r in rows if r[2] is not None)
    assert former.bridged == 4  # 1 + 3 lost frames interpolated
    assert former.short == 1 == sum(len(r) < 10 for r in expected)  # the 50 ms gap's block
    assert former.skipped == 1  # the duplicate
    spacing = np.diff(blocks.t)
    k = int(np.flatnonzero(blocks.frames < 10)[0])  # the short block, before the restart
    assert np.allclose(np.delete(spacing, [k - 1, k]), 0.01, atol=1e-9)  # the rest: even


def test_frame_by_frame_equals_chunks_to_the_bit(recorded):
    T, X, _ = recorded
    one = BlockFormer(10, 1000.0)
    points = [p for i in range(len(T)) for p in one.push(T[i], X[i, :7], X[i, 7:14], X[i, 14:], i)]
    many = BlockFormer(10, 1000.0)
    parts = [many.push_many(T[a:a + 337], X[a:a + 337], np.arange(a, min(a + 337, len(T))))
             for a in range(0, len(T), 337)]  # chunks that split blocks
    t = np.concatenate([p.t for p in parts])
    x = np.concatenate([p.X for p in parts])
    cycles = np.concatenate([p.cycle for p in parts])
    assert len(points) == len(t)
    assert np.array_equal([p.t for p in points], t)
    assert np.array_equal([p.features() for p in points], x)
    assert [p.cycle for p in points] == cycles.tolist()
    tail_one, tail_many = one.flush(), many.flush()
    assert tail_one.t == tail_many.t and np.array_equal(tail_one.q, tail_many.q)


def test_bad_block_sizes_and_frames_are_refused():
    with pytest.raises(InvalidInputError, match="integer >= 1"):
        BlockFormer(0)
    with pytest.raises(InvalidInputError, match=r"\(n, 21\)"):
        BlockFormer(10).push_many(np.zeros(3), np.zeros((3, 20)))


def test_the_online_loop_fed_frames_equals_the_loop_fed_its_blocks(recorded):
    """A replay hands the estimator blocks formed in bulk; the same frames pushed one by one
    through the online loop's own former give the same estimates, to the bit."""
    from sim.arm import NOMINAL_DYNAMICS
    from sim.robot import ArmModel

    T, X, _ = recorded
    kin = ArmModel()

    def fresh():
        model = PhysicsInformedEnsemble(dynamics=NOMINAL_DYNAMICS)
        return OnlineIdentifier(model, kin.flange_position, None, learn=False)

    by_frame = fresh()
    outs = []
    for i in range(len(T)):
        closed = by_frame.former.blocks
        out = by_frame.step(JointState(t=T[i], q=X[i, :7], dq=X[i, 7:14], tau_J=X[i, 14:],
                                       cycle=i))
        if by_frame.former.blocks > closed:  # this frame closed a block: its estimate
            outs.append(out)
        elif out is not None:  # the others hold the last one, without change or reset
            assert out[0].phi is outs[-1][0].phi or np.array_equal(out[0].phi, outs[-1][0].phi)
            assert not out[0].extra.get("change") and not out[0].extra.get("reset")
    by_block = fresh()
    blocks = BlockFormer(10, 1000.0).push_many(T, X, np.arange(len(T)))
    batch = [by_block.step_block(blocks.state(k)) for k in range(len(blocks))]
    assert len(outs) == len(batch) > 100
    assert np.array_equal([o[0].phi for o in outs], [b[0].phi for b in batch])
    assert np.array_equal([o[1] for o in outs], [b[1] for b in batch])
    assert np.isfinite(batch[-1][0].phi).all()


def test_a_bridge_longer_than_a_block_to_the_bit(recorded):
    """Blocks of 3 frames with gaps of 7 and 12 lost frames (both bridged: the bridge fills
    the block's buffer more than once) and a chunk that ends just before a gap: frame by
    frame, in chunks and the plain rule agree."""
    T, X, _ = recorded
    keep = np.ones(len(T), dtype=bool)
    keep[200:207] = False
    keep[600:612] = False
    T, X = T[keep], X[keep]
    one = BlockFormer(3, 1000.0)
    points = [p for i in range(len(T)) for p in one.push(T[i], X[i, :7], X[i, 7:14], X[i, 14:])]
    many = BlockFormer(3, 1000.0)
    parts = [many.push_many(T[a:b], X[a:b]) for a, b in ((0, 200), (200, 593), (593, len(T)))]
    assert np.array_equal([p.features() for p in points], np.concatenate([p.X for p in parts]))
    assert np.array_equal([p.t for p in points], np.concatenate([p.t for p in parts]))
    expected = _expected(T, X, size=3)
    assert len(points) == len(expected)
    for p, rows in zip(points, expected, strict=True):
        np.testing.assert_allclose(p.features(), np.mean([r[1] for r in rows], axis=0),
                                   rtol=0, atol=1e-12)
    assert one.bridged == many.bridged == 4 + 7 + 12  # the recording's own 1 and 3 too
