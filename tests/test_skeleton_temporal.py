"""The temporal skeleton model's window sampling and its place in the stage."""

from __future__ import annotations

import numpy as np
import pytest

from live.core.errors import ModelError
from models.skeleton.temporal import DEFAULT_TEMPORAL_MODEL, feature_size, sample_history


def _history(times, rng):
    return np.asarray(times, float), rng.normal(size=(len(times), 22, 3)), rng.random((len(times), 22))


def test_window_at_the_training_rate_is_the_past_frames_newest_first():
    rng = np.random.default_rng(0)
    t, j, c = _history(np.arange(20) / 30.0, rng)
    win = sample_history(t, j, c, t[-1], np.eye(4), window=8, fps=30.0)
    np.testing.assert_allclose(win.joints, j[::-1][:8], atol=1e-9)
    np.testing.assert_allclose(win.confidence, c[::-1][:8], atol=1e-9)
    assert win.observed.tolist() == [1.0] * 8
    assert win.features().shape == (feature_size(8),)


def test_window_interpolates_a_faster_camera_and_repeats_the_first_frame():
    rng = np.random.default_rng(1)
    t, j, c = _history(np.arange(7) / 60.0, rng)  # 60 fps, only 0.1 s of history
    win = sample_history(t, j, c, t[-1], np.eye(4), window=6, fps=30.0)
    # 30 fps samples fall on every other 60 fps frame, then before the first one.
    np.testing.assert_allclose(win.joints[:4], j[[6, 4, 2, 0]], atol=1e-9)
    np.testing.assert_allclose(win.joints[4:], j[[0, 0]], atol=1e-9)
    assert win.observed.tolist() == [1, 1, 1, 1, 0, 0]


def test_window_is_in_the_newest_person_frame():
    rng = np.random.default_rng(2)
    t, j, c = _history(np.arange(4) / 30.0, rng)
    yaw = 0.7
    to_world = np.eye(4)
    to_world[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    to_world[:3, 3] = (1.0, 0.0, -2.0)
    win = sample_history(t, j, c, t[-1], to_world, window=4, fps=30.0)
    back = win.joints @ to_world[:3, :3].T + to_world[:3, 3]
    np.testing.assert_allclose(back, j[::-1], atol=1e-9)


@pytest.mark.skipif(not DEFAULT_TEMPORAL_MODEL.is_file(), reason="no shipped temporal model")
def test_stage_uses_the_temporal_model_only_behind_its_regressor(tmp_path):
    from models.skeleton.runtime import BASELINE_MODEL, SkeletonStage

    assert SkeletonStage().temporal is not None
    assert SkeletonStage(temporal=False).temporal is None
    # The shipped temporal model was trained on the shipped regressor's errors, not the baseline's.
    assert SkeletonStage(BASELINE_MODEL).temporal is None
    with pytest.raises(ModelError, match="another skeleton model"):
        SkeletonStage(BASELINE_MODEL, temporal=DEFAULT_TEMPORAL_MODEL)


@pytest.mark.skipif(not DEFAULT_TEMPORAL_MODEL.is_file(), reason="no shipped temporal model")
def test_stage_takes_the_temporal_model_beside_its_regressor(tmp_path):
    """A regressor kept in its own folder (e.g. a mirror-averaged one) runs with the temporal
    models trained behind it there; the shipped ones are the fallback."""
    import shutil

    from models.skeleton.runtime import BASELINE_MODEL, DEFAULT_MODEL, SkeletonStage
    from models.skeleton.temporal import temporal_model_path

    own = tmp_path / "skeleton.onnx"
    shutil.copy(DEFAULT_MODEL, own)
    assert temporal_model_path(0, own) == DEFAULT_TEMPORAL_MODEL
    assert SkeletonStage(own).temporal.path == DEFAULT_TEMPORAL_MODEL
    for f in (DEFAULT_TEMPORAL_MODEL, DEFAULT_TEMPORAL_MODEL.with_suffix(".json")):
        shutil.copy(f, tmp_path / f.name)
    assert temporal_model_path(0, own) == tmp_path / DEFAULT_TEMPORAL_MODEL.name
    assert SkeletonStage(own).temporal.path == tmp_path / DEFAULT_TEMPORAL_MODEL.name
    # Beside another regressor, the same file does not match: refinement off, not wrong corrections.
    other = tmp_path / "other" / "skeleton.onnx"
    other.parent.mkdir()
    shutil.copy(BASELINE_MODEL, other)
    for f in (DEFAULT_TEMPORAL_MODEL, DEFAULT_TEMPORAL_MODEL.with_suffix(".json")):
        shutil.copy(f, other.parent / f.name)
    assert SkeletonStage(other).temporal is None


@pytest.mark.skipif(not DEFAULT_TEMPORAL_MODEL.is_file(), reason="no shipped temporal model")
def test_a_temporal_model_runs_behind_a_regressor_it_was_validated_behind(tmp_path):
    import json
    import shutil

    from models.skeleton.runtime import BASELINE_MODEL, SkeletonStage
    from models.skeleton.temporal import file_sha256

    regressor = tmp_path / "skeleton.onnx"
    shutil.copy(BASELINE_MODEL, regressor)
    shutil.copy(DEFAULT_TEMPORAL_MODEL, tmp_path / DEFAULT_TEMPORAL_MODEL.name)
    card = json.loads(DEFAULT_TEMPORAL_MODEL.with_suffix(".json").read_text())
    card_path = tmp_path / DEFAULT_TEMPORAL_MODEL.with_suffix(".json").name
    card_path.write_text(json.dumps(card))
    assert SkeletonStage(regressor).temporal is None
    card["validated_behind"] = [{"file": regressor.name, "sha256": file_sha256(regressor)}]
    card_path.write_text(json.dumps(card))
    assert SkeletonStage(regressor).temporal is not None


def test_missing_temporal_model_is_a_model_error(tmp_path):
    from models.skeleton.runtime import SkeletonStage

    with pytest.raises(ModelError, match="no temporal skeleton model"):
        SkeletonStage(temporal=tmp_path / "none.onnx")


LAG2_MODEL = DEFAULT_TEMPORAL_MODEL.with_name("skeleton_temporal_lag2.onnx")


def _feed(refiner, times_ns, rng):
    out = []
    for t in times_ns:
        out.append(refiner(int(t), rng.normal(size=(22, 3)), rng.random(22), np.eye(4)))
    return out


@pytest.mark.skipif(not LAG2_MODEL.is_file(), reason="no shipped lag-2 temporal model")
def test_lagging_model_estimates_an_earlier_frame_stamped_with_its_time():
    from models.skeleton.temporal import TemporalRefiner

    rng = np.random.default_rng(3)
    refiner = TemporalRefiner(LAG2_MODEL)
    assert refiner.lag == 2 and refiner.lag_s == pytest.approx(2 / 30)
    t30 = 1_000_000_000 + np.round(np.arange(10) * 1e9 / 30).astype(np.int64)
    got = _feed(refiner, t30, rng)
    assert got[0] is None and got[1] is None  # frames 0 and 1 come out with frames 2 and 3
    assert [g.t_ns for g in got[2:]] == t30[:-2].tolist()
    # At the stream's end the last two come from flush, once; finite, in the person frame's world
    owed = refiner.flush()
    assert [g.t_ns for g in owed] == t30[-2:].tolist() and refiner.flush() == []
    assert all(np.isfinite(g.joints).all() and g.joints.shape == (22, 3) for g in owed)
    # At 15 fps the 67 ms lag is one frame.
    refiner.reset()
    t15 = 1_000_000_000 + np.round(np.arange(6) * 1e9 / 15).astype(np.int64)
    got = _feed(refiner, t15, rng)
    assert got[0] is None and [g.t_ns for g in got[1:]] == t15[:-1].tolist()


def test_online_model_estimates_the_newest_frame():
    from models.skeleton.temporal import TemporalRefiner

    rng = np.random.default_rng(4)
    refiner = TemporalRefiner()
    assert refiner.lag == 0
    t = 1_000_000_000 + np.round(np.arange(5) * 1e9 / 30).astype(np.int64)
    got = _feed(refiner, t, rng)
    assert [g.t_ns for g in got] == t.tolist()
    assert refiner.flush() == []  # it owes nothing


def test_unknown_lag_is_a_user_error():
    from live.core.errors import UserInputError
    from models.skeleton.runtime import SkeletonStage

    with pytest.raises(UserInputError, match="lag 7"):
        SkeletonStage(lag=7)
    with pytest.raises(UserInputError, match="needs the temporal model"):
        SkeletonStage(temporal=False, lag=2)


def test_online_model_restarts_its_history_when_it_strays_from_the_frame():
    from live.body.library import load_body
    from models.skeleton.temporal import RESTART_DEVIATION_M, TemporalRefiner

    rest = np.asarray(load_body("adult_male_average").rest_joints, np.float64)
    rest = rest - rest[0] * np.array([1.0, 0.0, 1.0])  # the pelvis above the person frame's origin
    turned = rest @ np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).T  # a quarter turn
    refiner, to_world, conf = TemporalRefiner(), np.eye(4), np.ones(22)
    t = 1_000_000_000 + np.round(np.arange(24) * 1e9 / 30).astype(np.int64)
    for k in range(20):  # standing still: the model agrees with the frames
        out = refiner(int(t[k]), rest, conf, to_world)
        assert np.linalg.norm(out.joints - rest, axis=1).mean() < RESTART_DEVIATION_M
    assert refiner.restarts == 0
    # Turned a quarter in 33 ms: the history cannot explain it. One frame may be a fast move the
    # model catches up with; on the second the frame's own estimate is given.
    out = refiner(int(t[20]), turned, conf, to_world)
    assert refiner.restarts == 0 and np.linalg.norm(out.joints - turned, axis=1).mean() > RESTART_DEVIATION_M
    out = refiner(int(t[21]), turned, conf, to_world)
    assert refiner.restarts == 1 and np.array_equal(out.joints, turned)
    for k in range(22, 24):  # and the model follows from there
        out = refiner(int(t[k]), turned, conf, to_world)
        assert np.linalg.norm(out.joints - turned, axis=1).mean() < RESTART_DEVIATION_M
    assert refiner.restarts == 1


@pytest.mark.parametrize("lag", [0, 2])
def test_history_starts_again_where_the_frames_jump_to_something_else(lag):
    from live.body.library import load_body
    from models.skeleton.temporal import TemporalRefiner, temporal_model_path

    rest = np.asarray(load_body("adult_male_average").rest_joints, np.float64)
    rest = rest - rest[0] * np.array([1.0, 0.0, 1.0])
    clutter, performer = rest + np.array([1.5, 0.0, 0.5]), rest  # the finder's pick moves 1.6 m
    path, conf, to_world = temporal_model_path(lag), np.ones(22), np.eye(4)
    t = 1_000_000_000 + np.round(np.arange(30) * 1e9 / 30).astype(np.int64)
    refiner, fresh = TemporalRefiner(path), TemporalRefiner(path)
    for k in range(12):  # on a still box figure first
        refiner(int(t[k]), clutter, conf, to_world)
    assert refiner.jumps == 0
    # From the jump on, the estimates are those of a refiner that never saw the figure.
    outs, fresh_outs = [], []
    for k in range(12, 30):
        body = performer + 0.01 * np.sin(k) * np.array([1.0, 0.0, 0.0])
        outs.append(refiner(int(t[k]), body, conf, to_world))
        fresh_outs.append(fresh(int(t[k]), body, conf, to_world))
    assert refiner.jumps == 1
    after = [o for o in outs if o is not None and o.t_ns >= t[12]]
    assert len(after) == len(fresh_outs) - lag
    for a, b in zip(after, [o for o in fresh_outs if o is not None]):
        assert a.t_ns == b.t_ns and np.array_equal(a.joints, b.joints)
    # A lagging model still owes, and gives, the figure's last frames before the jump.
    assert [o.t_ns for o in outs if o is not None and o.t_ns < t[12]] == [int(x) for x in t[12 - lag:12]]


def _standing():
    from live.body.library import load_body

    rest = np.asarray(load_body("adult_male_average").rest_joints, np.float64)
    return rest - rest[0] * np.array([1.0, 0.0, 1.0])  # the pelvis above the person frame's origin


def _turned(joints, deg):
    a = np.radians(deg)
    turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return (joints - joints[0]) @ turn.T + joints[0]


@pytest.mark.parametrize("lag", [0, 2])
def test_a_stream_of_unrelated_stills_is_read_frame_by_frame(lag):
    """A folder of stills (one pose each, at about one place) is no take: once most recent frames
    break from the one before, each frame comes out as the regressor read it, the last ones of
    a lagging model's stream too."""
    from models.skeleton.temporal import BREAK_POSE_M, STILLS_BREAKS, TemporalRefiner, pose_change, temporal_model_path

    rng = np.random.default_rng(5)
    standing = _standing()
    stills = [_turned(standing, 100.0 * k) + rng.normal(0, 0.05, (22, 3)) * [1, 0, 1] for k in range(24)]
    assert all(pose_change(b, a) > BREAK_POSE_M for a, b in zip(stills, stills[1:]))
    refiner, conf = TemporalRefiner(temporal_model_path(lag)), np.ones(22)
    t = 1_000_000_000 + np.round(np.arange(24) * 1e9 / 30).astype(np.int64)
    outs = [refiner(int(t[k]), stills[k], conf, np.eye(4)) for k in range(24)] + refiner.flush()
    outs = [o for o in outs if o is not None]
    assert [o.t_ns for o in outs] == t.tolist()
    # Frame STILLS_BREAKS is the first after STILLS_BREAKS breaks; a lagging model gives it, and
    # those it still owed then, lag frames later, when it knows.
    first = STILLS_BREAKS - lag
    assert all(np.array_equal(out.joints, stills[k]) for k, out in enumerate(outs) if k >= first)
    assert refiner.stills == 24 - first


@pytest.mark.parametrize("lag", [0, 2])
def test_a_take_with_frames_read_turned_is_not_taken_for_stills(lag):
    """A performer read turned on a frame now and then breaks the pose as stills do, but not on
    most frames: the temporal model keeps smoothing."""
    from models.skeleton.temporal import TemporalRefiner, temporal_model_path

    standing = _standing()
    refiner, conf = TemporalRefiner(temporal_model_path(lag)), np.ones(22)
    t = 1_000_000_000 + np.round(np.arange(40) * 1e9 / 30).astype(np.int64)
    for k in range(40):
        pose = standing + 0.003 * k * np.array([1.0, 0.0, 0.0])
        refiner(int(t[k]), _turned(pose, 180.0) if k % 5 == 4 else pose, conf, np.eye(4))  # every fifth frame
    refiner.flush()
    assert refiner.stills == 0


def test_stage_counts_the_frames_it_gave_as_stills():
    from models.skeleton.runtime import SkeletonStage

    stage = SkeletonStage()
    assert stage.counters["temporal_stills"] == 0
    stage.temporal.stills = 3  # as the refiner counts them
    assert stage.counters["temporal_stills"] == 3
    assert SkeletonStage(temporal=False).counters["temporal_stills"] == 0


@pytest.mark.skipif(not LAG2_MODEL.is_file(), reason="no shipped lag-2 temporal model")
def test_lagging_model_gives_every_frame_when_the_finder_missed_one():
    """Frames the finder missed get no skeleton; the ones it found all do, in order, the frames
    owed at a gap a frame later each."""
    from models.skeleton.temporal import TemporalRefiner

    rng = np.random.default_rng(6)
    refiner = TemporalRefiner(LAG2_MODEL)
    t30 = 1_000_000_000 + np.round(np.arange(16) * 1e9 / 30).astype(np.int64)
    found = np.delete(t30, [5, 9, 10])  # nobody in view on three frames
    got = [g for g in _feed(refiner, found, rng) + refiner.flush() if g is not None]
    assert [g.t_ns for g in got] == found.tolist()
