"""research.facing_sequences: runs of turned frames and the facing guard it measures."""

from __future__ import annotations

import numpy as np

from live.core.skeleton import default_rest_joints
from research.facing_sequences import FacingGuard, guarded, runs, turned_frames


def test_runs_of_turned_frames_skip_frames_the_finder_missed():
    flags = np.array([[True, True, False, True, False, True]])
    found = np.array([[True, True, True, True, False, True]])
    assert runs(flags, found) == [2, 2]  # the missed frame does not end the last run


def test_the_facing_guard_holds_a_sudden_turn_then_follows_a_lasting_one():
    rest = default_rest_joints()
    away = rest * np.array([-1.0, 1.0, -1.0])  # read facing away
    guard = FacingGuard(max_turn_deg=90.0, max_run=2)
    out = [guard(j + [0.01 * k, 0.0, 0.0]) for k, j in enumerate([rest, away, away, away, away])]
    assert np.allclose(out[1], rest + [0.01, 0.0, 0.0])  # held, moved with the pelvis
    assert np.allclose(out[2], rest + [0.02, 0.0, 0.0])
    assert np.allclose(out[3], away + [0.03, 0.0, 0.0])  # a third frame in a row: followed
    truth = np.stack([rest] * 5)[None]
    world = np.stack([rest, away, away, away, away])[None]
    found = np.ones((1, 5), bool)
    assert turned_frames(world, truth, found).sum() == 4
    assert turned_frames(guarded(world, found, False, {"max_turn_deg": 90.0, "max_run": 2}), truth, found).sum() == 2
