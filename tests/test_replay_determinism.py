"""Replays at max speed are deterministic: byte-identical result files, every frame processed."""

import json

import pytest

from live.app.cli import main
from live.io.results import read_avatar, read_skeleton
from sim.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_bvh):
    path = tmp_path_factory.mktemp("s") / "s.mcap"
    synthesize(SynthOptions(motion=str(shared_bvh / "cc_002_05.bvh"), body="performer", seconds=1.0, start_s=2.0,
                            imu="xbus", seed=1), path)
    return path


def test_two_replays_write_identical_files(session, tmp_path):
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        assert main(["replay", str(session), "--out", str(out), "--avatar", "default", "--quiet"]) == 0
        outs.append(out)
    stats = json.loads((outs[0] / "stats.json").read_text())
    assert stats["frames"] == 30 and stats["drops"] == {"ring_overwrites": 0, "skipped_for_latest": 0}
    files = sorted(p.name for p in outs[0].iterdir() if p.name != "stats.json")
    assert files == sorted(p.name for p in outs[1].iterdir() if p.name != "stats.json")
    for name in files:
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name


LAG2 = pytest.importorskip("models.skeleton.temporal").temporal_model_path(2)


@pytest.mark.skipif(not LAG2.is_file(), reason="no shipped lag-2 temporal model")
def test_lagging_replay_keeps_frame_times_scores_them_and_stays_deterministic(session, tmp_path):
    import numpy as np

    outs = []
    for k in range(2):
        out = tmp_path / f"lag{k}"
        assert main(["replay", str(session), "--out", str(out), "--avatar", "default", "--lag", "2", "--quiet"]) == 0
        outs.append(out)
    online = tmp_path / "online"
    assert main(["replay", str(session), "--out", str(online), "--quiet"]) == 0
    lag, now = read_skeleton(outs[0] / "skeleton.npz"), read_skeleton(online / "skeleton.npz")
    t_lag, t_now, t_avatar = lag.t_ns, now.t_ns, read_avatar(outs[0] / "avatar.npz").t_ns
    changed = not np.array_equal(lag.joints, now.joints)
    # Frames of the online run, stamped with their own times, smoothed; the last two drained at
    # the session's end; after a gap in the finder's frames the lagging model goes on from the
    # newest frame old enough, as live. The avatar's poses are of the skeletons' instants.
    assert set(t_lag.tolist()) <= set(t_now.tolist()) and np.all(np.diff(t_lag) > 0) and changed
    assert t_lag[-1] == t_now[-1] and len(t_lag) >= len(t_now) - 2
    assert np.array_equal(t_avatar, t_lag)
    stats = json.loads((outs[0] / "stats.json").read_text())
    # what the model still owed at the end: the last frame or two (fewer after a finder's gap)
    assert 1 <= stats["drained"] == stats["stages"]["skeleton"]["counters"]["flushed"] <= 2
    assert stats["accuracy"]["frames_scored"] == len(t_lag)
    assert stats["skeleton_lag_ms"] == pytest.approx(66.7)
    assert stats["accuracy"]["mpjpe_mm"] < 80
    for name in ("skeleton.npz", "avatar.npz", "avatar.bvh"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name


def test_fused_replay_refuses_a_lag(session, tmp_path, capsys):
    if not LAG2.is_file():
        pytest.skip("no shipped lag-2 temporal model")
    code = main(["replay", str(session), "--out", str(tmp_path / "f"), "--only", "fused", "--lag", "2", "--quiet"])
    assert code == 2
    assert "--lag 0" in capsys.readouterr().err
