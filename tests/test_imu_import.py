"""Recorded suits in (live.io.imu_import_*, live.imu.importing, ``livecap import``).

No real MVNX or Xsens DOT recording is at hand, so this module writes them: ``write_mvnx`` and
``write_dot`` are small generators of those formats (the layouts of docs/imu.md, "Recorded
suits") from a simulated suit on a CMU walk: a performer holding a calibration pose, then
walking; sensors strapped with random mountings (DOT) or MVN's own segment frames (MVNX). The
real x-IMU3 lower-body take of ../shared/data/real_imu is read as it is.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from live.app.cli import main
from live.core.heading import yaw_of, yaw_quat
from live.core.kinematics import forward_kinematics, global_rotations
from live.core.rotations import matrix_to_quat, quat_conjugate, quat_multiply, quat_normalize
from live.core.skeleton import JOINT_INDEX as J
from live.imu.importing import import_session, layout_for
from live.io.imu_import import world_quat
from live.io.imu_import_dot import read_dot
from live.io.imu_import_mvnx import read_mvnx
from live.io.session import SessionReader

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_imu" / "ximu3_lower_body"
RATE = 60.0
#: MVN's segments (MVN User Manual), in its order; T12 has no canonical joint.
MVN_SEGMENTS = ("Pelvis", "L5", "L3", "T12", "T8", "Neck", "Head", "RightShoulder", "RightUpperArm", "RightForeArm",
                "RightHand", "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand", "RightUpperLeg",
                "RightLowerLeg", "RightFoot", "RightToe", "LeftUpperLeg", "LeftLowerLeg", "LeftFoot", "LeftToe")
MVN_JOINT = {"Pelvis": "pelvis", "L5": "spine1", "L3": "spine2", "T12": "spine2", "T8": "spine3", "Neck": "neck",
             "Head": "head", "RightShoulder": "right_collar", "RightUpperArm": "right_shoulder",
             "RightForeArm": "right_elbow", "RightHand": "right_wrist", "LeftShoulder": "left_collar",
             "LeftUpperArm": "left_shoulder", "LeftForeArm": "left_elbow", "LeftHand": "left_wrist",
             "RightUpperLeg": "right_hip", "RightLowerLeg": "right_knee", "RightFoot": "right_ankle",
             "RightToe": "right_foot", "LeftUpperLeg": "left_hip", "LeftLowerLeg": "left_knee",
             "LeftFoot": "left_ankle", "LeftToe": "left_foot"}
MVN_SENSORS = ("Pelvis", "T8", "Head", "RightUpperArm", "RightForeArm", "RightHand", "LeftUpperArm", "LeftForeArm",
               "LeftHand", "RightUpperLeg", "RightLowerLeg", "RightFoot", "LeftUpperLeg", "LeftLowerLeg", "LeftFoot")
#: MVN's segment axes (x forward, y left, z up) in the canonical segment frame (x left, y up, z forward).
MVN_FRAME = matrix_to_quat(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))


@pytest.fixture(scope="module")
def walk(shared_bvh):
    """A performer holding an N-pose for 1.5 s, then walking (cc_007_04) at 60 Hz: local
    rotations (T, 22, 4), root (T, 3), rest (22, 3), global rotations (T, 22, 4), the hold's
    last sample index, and the facing during the hold (radians)."""
    from live.motion.cleaning import trim_bind_pose
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion
    from sim.imu_stream import calibration_prelude

    m = resample(trim_bind_pose(load_motion(shared_bvh / "cc_007_04.bvh")), RATE)
    pre = calibration_prelude(m.rotations[0], "npose", m.rest_joints, 1.5, 0.3, RATE)
    rot = np.concatenate([pre, m.rotations]).astype(np.float64)
    root = np.concatenate([np.broadcast_to(m.root[0], (len(pre), 3)), m.root])
    return {"rot": rot, "root": root, "rest": np.asarray(m.rest_joints, np.float64), "glob": global_rotations(rot),
            "hold_end": int(1.5 * RATE), "facing": float(yaw_of(rot[0, 0]))}


def _to_world(q: np.ndarray, world: str) -> np.ndarray:
    """livecap-world quaternions -> the file's world (the inverse of live.io.imu_import.to_livecap)."""
    return quat_normalize(quat_multiply(quat_conjugate(world_quat(world)), q))


def write_mvnx(path: Path, walk: dict, *, segments=MVN_SEGMENTS, tpose: bool = True, seed: int = 0) -> None:
    """An MVNX file of the walk: MVN segments (orientation: the canonical global rotation in MVN's
    world and segment axes), the sensors strapped with random mountings (sensorOrientation), the
    identity / tpose / tpose-isb reference frames, one normal frame per sample (time in ms)."""
    rng = np.random.default_rng(seed)
    glob = walk["glob"]
    seg_q = np.stack([_to_world(quat_multiply(glob[:, J[MVN_JOINT[s]]], MVN_FRAME), "NWU") for s in segments], 1)
    mount = quat_normalize(rng.normal(size=(len(MVN_SENSORS), 4)))
    sen_q = np.stack([quat_multiply(seg_q[:, segments.index(s)], mount[k]) for k, s in enumerate(MVN_SENSORS)], 1)
    t_q = _to_world(quat_multiply(yaw_quat(walk["facing"]), MVN_FRAME), "NWU")

    def numbers(a: np.ndarray) -> str:
        return " ".join(f"{v:.6f}" for v in np.asarray(a).ravel())

    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<mvnx version="4" xmlns="http://www.xsens.com/mvn/mvnx">',
             '<mvn version="2022.0.0" build="0"/>', "<comment></comment>",
             f'<subject label="walker" frameRate="{RATE:g}" segmentCount="{len(segments)}" configuration="FullBody">',
             "<segments>"]
    lines += [f'<segment label="{s}" id="{k + 1}"><points></points></segment>' for k, s in enumerate(segments)]
    lines += ["</segments>", "<sensors>"] + [f'<sensor label="{s}"/>' for s in MVN_SENSORS] + ["</sensors>"]
    lines.append(f'<frames segmentCount="{len(segments)}" sensorCount="{len(MVN_SENSORS)}" jointCount="22">')
    ident = np.tile([1.0, 0.0, 0.0, 0.0], len(segments))
    lines.append(f'<frame time="0" type="identity"><orientation>{numbers(ident)}</orientation></frame>')
    if tpose:
        lines.append(f'<frame time="0" type="tpose"><orientation>{numbers(np.tile(t_q, len(segments)))}</orientation></frame>')
        lines.append(f'<frame time="0" type="tpose-isb"><orientation>{numbers(ident)}</orientation></frame>')
    for k in range(len(glob)):
        lines.append(f'<frame time="{int(round(k * 1000 / RATE))}" index="{k}" tc="00:00:00:00" ms="{k}" type="normal">'
                     f"<orientation>{numbers(seg_q[k])}</orientation>"
                     f"<position>{numbers(np.zeros(3 * len(segments)))}</position>"
                     f"<sensorOrientation>{numbers(sen_q[k])}</sensorOrientation></frame>")
    lines += ["</frames>", "</subject>", '<securityCode code="0"/>', "</mvnx>"]
    path.write_text("\n".join(lines))


DOT_TAGS = {"Pelvis": "pelvis", "LFemur": "left_hip", "RFemur": "right_hip", "LTibia": "left_knee",
            "RTibia": "right_knee", "LFoot": "left_ankle", "RFoot": "right_ankle"}


def write_dot(folder: Path, walk: dict, *, seed: int = 1, drop: float = 0.03, euler_for: tuple[str, ...] = ("LFoot",),
              start_tick: int = 2**32 - 500_000) -> list[Path]:
    """Xsens DOT app exports of a lower-body suit on the walk: one CSV per sensor (preamble,
    PacketCounter, SampleTimeFine in microseconds starting just before its 32-bit wrap, the
    orientation to ENU as Quat_* or, for ``euler_for``, Euler_* with Acc/Gyr), sensors strapped
    at random orientations, ``drop`` of the packets missing."""
    from live.core.rotations import quat_to_matrix

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for n, (tag, joint) in enumerate(DOT_TAGS.items()):
        mount = quat_normalize(rng.normal(size=4))
        q = _to_world(quat_multiply(walk["glob"][:, J[joint]], mount), "ENU")
        keep = rng.random(len(q)) >= drop
        keep[: int(RATE)] = True
        mac = f"D4CA6EF1{n:04X}"
        path = folder / f"{tag}_{mac}_20240101_120000.csv"
        euler = tag in euler_for
        head = ["sep=,", f"DeviceTag:,{tag}", "FirmwareVersion:,2.0.0", "AppVersion:,2021.0", "SyncStatus:,Synced",
                f"OutputRate:,{RATE:g}Hz", "FilterProfile:,General", "StartTime: ,2024-01-01_12:00:00_000 GMT+1",
                "© Xsens Technologies B. V. 2005-2021", ""]
        head.append("PacketCounter,SampleTimeFine," + ("Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z"
                                                        if euler else "Quat_W,Quat_X,Quat_Y,Quat_Z,FreeAcc_X,FreeAcc_Y,FreeAcc_Z,Status"))
        rows = []
        for k in np.flatnonzero(keep):
            tick = (start_tick + int(round(k * 1e6 / RATE))) % 2**32
            if euler:
                m = quat_to_matrix(q[k])
                roll, pitch, yaw = (np.degrees(np.arctan2(m[2, 1], m[2, 2])), np.degrees(np.arcsin(-m[2, 0])),
                                    np.degrees(np.arctan2(m[1, 0], m[0, 0])))
                rows.append(f"{k},{tick},{roll:.6f},{pitch:.6f},{yaw:.6f},0,0,9.81,0,0,0")
            else:
                rows.append(f"{k},{tick}," + ",".join(f"{v:.6f}" for v in q[k]) + ",0,0,0,0")
        path.write_text("\n".join(head + rows) + "\n")
        out.append(path)
    return out


def _replay_imu(session: Path, rest: np.ndarray, world_yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns (T,), joints (T, 22, 3)) of the session through the suit-only stage."""
    from live.imu.stage import ImuSkeletonStage, suit_options_from_stream
    from live.pipeline.runner import Pipeline
    from sim.replay import ReplaySource

    source = ReplaySource(session)
    stages = [ImuSkeletonStage(rest_joints=rest, world_yaw=world_yaw, **suit_options_from_stream(source.streams()[0].meta))]
    rows = []
    Pipeline([source], stages, mode="every", on_result=lambda r: rows.append((r.t_ns, r.skeleton.joints))
             if r.skeleton is not None else None).run(threading.Event())
    return np.array([a for a, _ in rows]), np.array([b for _, b in rows], np.float64)


def _relative_error(joints: np.ndarray, t_ns: np.ndarray, walk: dict, joint_ids) -> float:
    """Mean error (m) of the joints against the pelvis, against the walk's truth at the same times."""
    truth, _ = forward_kinematics(walk["rot"], walk["root"], walk["rest"])
    k = np.round((t_ns - t_ns[0]) * 1e-9 * RATE).astype(int) + int(round((t_ns[0] - 1_000_000_000) * 1e-9 * RATE))
    k = np.clip(k, 0, len(truth) - 1)
    rel = joints - joints[:, :1]
    true_rel = truth[k] - truth[k, :1]
    return float(np.linalg.norm(rel[:, joint_ids] - true_rel[:, joint_ids], axis=-1).mean())


@pytest.mark.parametrize("stream", ["segments", "sensors"])
def test_mvnx_segments_and_sensors_replay_as_the_walk(walk, tmp_path, stream):
    path = tmp_path / "take.mvnx"
    write_mvnx(path, walk)
    rec = read_mvnx(path, stream=stream)
    suit, rows, dropped = layout_for(rec)
    if stream == "segments":
        assert dropped == ["T12"] and suit.size == 22  # every canonical joint from its MVN segment
    else:
        assert suit.size == len(MVN_SENSORS) and not dropped
    out = tmp_path / "take.mcap"
    report = import_session("mvnx", [path], out, stream=stream)
    assert report.calibration == "file" and report.packets == len(walk["rot"])
    t, joints = _replay_imu(out, walk["rest"], walk["facing"])
    assert len(t) >= len(walk["rot"]) - 2
    # The file's calibration makes every measured segment exact: all 22 joints from MVN's
    # segments; from its 15 sensors, the legs (the spine between pelvis and T8 is interpolated).
    legs = [J[f"{s}_{n}"] for s in ("left", "right") for n in ("hip", "knee", "ankle", "foot")]
    joints_scored = list(range(22)) if stream == "segments" else legs
    assert _relative_error(joints, t, walk, joints_scored) < 0.002


def test_dot_lower_body_calibrates_from_the_take(walk, tmp_path):
    files = write_dot(tmp_path / "dot", walk)
    rec = read_dot(tmp_path / "dot")
    assert {t.label for t in rec.tracks} == set(DOT_TAGS) and rec.meta["synced"]
    assert all(np.all(np.diff(t.t_s) > 0) for t in rec.tracks)  # across the counter's wrap
    out = tmp_path / "dot.mcap"
    report = import_session("xsens-dot", files, out)
    assert report.calibration == "take" and report.still_s[1] > 1.0
    hinge = [how for how in report.facing.values() if "hinge" in how]
    assert len(hinge) == 6  # thighs, shanks, feet found their facing from the walk
    t, joints = _replay_imu(out, walk["rest"], walk["facing"])
    legs = [J[f"{s}_{n}"] for s in ("left", "right") for n in ("knee", "ankle", "foot")]
    assert _relative_error(joints, t, walk, legs) < 0.03


def test_real_ximu3_take_walks_on_the_floor():
    if not REAL.is_dir():
        pytest.skip("../shared/data/real_imu is not present")
    from research.imu_real_figure import gait_checks, solve_recording

    t, joints = solve_recording(REAL)
    checks = gait_checks(t, joints)
    assert checks["steps"] >= 6 and checks["alternating_share"] >= 0.8  # feet alternate
    assert checks["lowest_foot_m"] >= -0.02  # no foot below the floor by more than 2 cm
    assert checks["knee_bent_frames"] > 100 and checks["knee_forward_share"] >= 0.95  # knees bend forward


def test_import_cli_and_replay(walk, tmp_path, capsys):
    files = write_dot(tmp_path / "dot", walk, euler_for=())
    out = tmp_path / "s.mcap"
    assert main(["import", "xsens-dot", str(tmp_path / "dot"), "--out", str(out)]) == 0
    assert "LFemur" in capsys.readouterr().out
    info = SessionReader(out).info
    assert [s.kind for s in info.streams] == ["imu"] and "layout" in info.streams[0].meta
    assert main(["import", "xsens-dot", *map(str, files), "--out", str(out)]) == 2  # exists: --force
    assert main(["import", "xsens-dot", *map(str, files), "--out", str(out), "--force"]) == 0
    res = tmp_path / "res"
    assert main(["replay", str(out), "--out", str(res), "--quiet"]) == 0  # the suit alone, no --only needed
    z = np.load(res / "skeleton.npz")
    assert len(z["t_ns"]) > 100 and np.isfinite(z["joints"]).all()


def test_layout_by_label_when_the_file_names_no_segments(walk, tmp_path, capsys):
    import json

    folder = tmp_path / "dot"
    for k, f in enumerate(write_dot(folder, walk, euler_for=())):
        text = f.read_text().replace(f"DeviceTag:,{list(DOT_TAGS)[k]}", f"DeviceTag:,sensor{k}")
        f.write_text(text)
    out = tmp_path / "s.mcap"
    assert main(["import", "xsens-dot", str(folder), "--out", str(out)]) == 2
    assert "give --layout" in capsys.readouterr().err
    layout = tmp_path / "layout.json"
    layout.write_text(json.dumps({"sensors": {f"sensor{k}": seg for k, seg in enumerate(DOT_TAGS.values())}}))
    assert main(["import", "xsens-dot", str(folder), "--out", str(out), "--layout", str(layout)]) == 0


def _bad_files(tmp_path: Path, walk: dict) -> list[tuple[str, Path, str]]:
    cases = []
    good = tmp_path / "good.mvnx"
    write_mvnx(good, walk)
    text = good.read_text()
    for name, content in {"truncated.mvnx": text[: len(text) // 2],
                          "numbers.mvnx": text.replace('type="normal"><orientation>', 'type="normal"><orientation>abc ', 1),
                          "entities.mvnx": '<?xml version="1.0"?><!DOCTYPE a [<!ENTITY x "y">]><mvnx/>',
                          "empty.mvnx": ""}.items():
        (tmp_path / name).write_text(content)
        cases.append(("mvnx", tmp_path / name, name))
    notpose = tmp_path / "notpose.mvnx"
    write_mvnx(notpose, walk, tpose=False)
    cases.append(("mvnx", notpose, "tpose"))
    dot = tmp_path / "dot.csv"
    dot.write_text("sep=,\nDeviceTag:,Pelvis\n\nPacketCounter,SampleTimeFine,FreeAcc_X\n0,1,0\n1,2,0\n")
    cases.append(("xsens-dot", dot, "orientation"))
    dot2 = tmp_path / "dot2.csv"
    dot2.write_text("sep=,\nDeviceTag:,Pelvis\n\nPacketCounter,SampleTimeFine,Quat_W,Quat_X,Quat_Y,Quat_Z\n"
                    "0,1,1,0,0,0\n1,2,one,0,0,0\n")
    cases.append(("xsens-dot", dot2, "not a number"))
    (tmp_path / "x" / "dev").mkdir(parents=True)
    cases.append(("ximu3", tmp_path / "x", "Quaternion.csv"))
    (tmp_path / "x2" / "Pelvis 64F0EDBF").mkdir(parents=True)
    (tmp_path / "x2" / "Pelvis 64F0EDBF" / "Quaternion.csv").write_bytes(b"\xff\xfe\x00garbage")
    cases.append(("ximu3", tmp_path / "x2", "Quaternion.csv"))
    return cases


def test_bad_files_give_one_line_and_exit_2(walk, tmp_path, capsys):
    for fmt, path, expect in _bad_files(tmp_path, walk):
        code = main(["import", fmt, str(path), "--out", str(tmp_path / "out.mcap")])
        err = capsys.readouterr().err.strip()
        assert code == 2, (path.name, err)
        assert len(err.splitlines()) == 1 and expect in err, (path.name, err)
        assert "Traceback" not in err
        assert not (tmp_path / "out.mcap").exists()
