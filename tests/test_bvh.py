"""BVH reader/writer: parsing any channel layout, FK, units, round trips, malformed files."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from live.core.errors import FormatError
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_from_axis_angle, quat_normalize
from live.core.skeleton import JOINT_NAMES, default_rest_joints
from live.io.bvh_kinematics import bvh_forward_kinematics, rest_positions
from live.io.bvh_reader import UNIT_SCALES, guess_scale, parse_bvh, read_bvh
from live.io.bvh_writer import clip_from_rotations, format_bvh, write_bvh, write_canonical_bvh

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "bvh"
needs_data = pytest.mark.skipif(not (DATA / "index.csv").exists(), reason="../shared/data/bvh missing")

# Two joints with different rotation orders, a non-root position channel, a partial rotation
# (one channel) and end sites.
SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT Arm
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Hand
    {
      OFFSET 2 0 0
      CHANNELS 4 Xposition Yposition Zposition Xrotation
      End Site
      {
        OFFSET 0 0 1
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.1
0 0 0 0 0 0 0 0 0 2 0 0 0
10 20 30 90 0 0 0 0 90 3 0 0 90
"""


def _small(text: str = SMALL):
    return parse_bvh(text, path="small.bvh")


def test_parse_small_structure():
    clip = _small()
    sk = clip.skeleton
    assert sk.names == ("Hips", "Arm", "Hand")
    assert sk.parents.tolist() == [-1, 0, 1]
    assert sk.channels[2] == ("Xposition", "Yposition", "Zposition", "Xrotation")
    assert sk.num_channels == 13
    assert sk.end_names() == ("Hand/end",)
    assert clip.num_frames == 2 and clip.fps == pytest.approx(10.0)
    np.testing.assert_allclose(rest_positions(sk, end_sites=True),
                               [[0, 0, 0], [1, 0, 0], [3, 0, 0], [3, 0, 1]])


def test_fk_follows_channel_order_and_position_channels():
    pos, glob = bvh_forward_kinematics(_small(), end_sites=True)
    # Frame 0: zero rotations, the Hand's position channels (2, 0, 0) replace its offset.
    np.testing.assert_allclose(pos[0], [[0, 0, 0], [1, 0, 0], [3, 0, 0], [3, 0, 1]], atol=1e-12)
    # Frame 1: root at (10,20,30) turned 90 deg about +y: +x -> -z. Arm turns 90 deg about its
    # own y (last of ZXY): its child offset (3,0,0) -> (0,0,-3) locally, then the root's yaw.
    # The hand's 90 deg about x sends the end site (0,0,1) to (0,-1,0).
    r_y = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)
    arm = np.array([10, 20, 30]) + r_y @ [1, 0, 0]
    hand = arm + r_y @ r_y @ [3, 0, 0]
    end = hand + r_y @ r_y @ np.array([0, -1, 0])
    np.testing.assert_allclose(pos[1], [[10, 20, 30], arm, hand, end], atol=1e-9)
    np.testing.assert_allclose(glob[1, 0], r_y, atol=1e-12)


def test_scale_applies_to_offsets_and_positions_only():
    clip = parse_bvh(SMALL, scale=0.5)
    np.testing.assert_allclose(clip.skeleton.offsets[1], [0.5, 0, 0])
    np.testing.assert_allclose(clip.root_positions()[1], [5, 10, 15])
    np.testing.assert_allclose(clip.channels[1, 3], 90.0)  # degrees untouched
    np.testing.assert_allclose(clip.local_translations()[1, 2], [1.5, 0, 0])


def test_guess_scale_units():
    sk = _small().skeleton
    for unit in ("m", "cm", "inch", "cmu", "mm"):
        body = sk.scaled(2.3 / UNIT_SCALES[unit] / 4.0)  # span of SMALL is 4 units
        assert guess_scale(body) == pytest.approx(UNIT_SCALES[unit]), unit


def test_round_trip_text():
    clip = _small()
    again = parse_bvh(format_bvh(clip))
    assert again.skeleton.names == clip.skeleton.names
    assert again.skeleton.channels == clip.skeleton.channels
    np.testing.assert_allclose(again.channels, clip.channels, atol=1e-6)
    np.testing.assert_allclose(again.skeleton.end_offsets, clip.skeleton.end_offsets)
    assert again.frame_time == pytest.approx(clip.frame_time)


@pytest.mark.parametrize("text, line, words", [
    (SMALL.split("MOTION")[0], None, "missing MOTION"),
    (SMALL.replace("0 0 0 0 0 0 0 0 0 2 0 0 0", "0 0 0 0 0 0 0 0 0 2 0 0"), 24, "12 values"),
    (SMALL.replace("10 20 30 90", "10 abc 30 90"), 25, "non-number 'abc'"),
    (SMALL.replace("10 20 30 90", "10 nan 30 90"), 25, "NaN"),
    (SMALL.replace("Frames: 2", "Frames: 3"), 25, "truncated MOTION"),
    (SMALL.replace("      }\n    }\n  }\n}\nMOTION", "      }\n    }\nMOTION"), 19, "truncated HIERARCHY"),
    (SMALL.replace("OFFSET 1 0 0", "OFFSET 1 x 0"), 8, "non-number"),
    (SMALL.replace("CHANNELS 3 Zrotation", "CHANNELS 3 Wrotation"), 9, "unknown channel"),
    (SMALL.replace("Frame Time: 0.1", "Frame Time: -1"), 23, "frame time"),
    ("hello\n", None, "unexpected 'hello'"),
])
def test_malformed_files_raise_format_error_with_line(text, line, words):
    with pytest.raises(FormatError) as info:
        parse_bvh(text, path="bad.bvh")
    msg = str(info.value)
    assert msg.startswith("bad.bvh")
    assert words.lower() in msg.lower()
    if line is not None:
        assert info.value.line == line, msg


def test_read_missing_file(tmp_path):
    with pytest.raises(FormatError, match="cannot read"):
        read_bvh(tmp_path / "nope.bvh")


def test_clip_from_rotations_round_trip():
    rng = np.random.default_rng(3)
    clip = _small(SMALL.replace("CHANNELS 4 Xposition Yposition Zposition Xrotation",
                                "CHANNELS 3 Yrotation Zrotation Xrotation")
                  .replace(" 2 0 0 0\n", " 0 0 0\n").replace(" 3 0 0 90\n", " 0 0 90\n"))
    q = quat_normalize(rng.normal(size=(5, 3, 4)))
    root = rng.normal(size=(5, 3))
    enc = clip_from_rotations(clip.skeleton, 0.05, q, root)
    back = parse_bvh(format_bvh(enc, precision=9))
    dots = np.abs(np.sum(back.local_quaternions() * q, -1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    np.testing.assert_allclose(back.root_positions(), root, atol=1e-8)


def test_write_canonical_bvh_fk_matches(tmp_path):
    rng = np.random.default_rng(0)
    rest = default_rest_joints(1.6)
    rot = quat_from_axis_angle(rng.normal(scale=0.4, size=(7, 22, 3)))
    root = rng.normal(size=(7, 3)) + [0, 1, 0]
    path = tmp_path / "avatar.bvh"
    write_canonical_bvh(path, rot, root, rest, fps=30)
    clip = read_bvh(path)
    assert clip.fps == pytest.approx(30.0)
    pos, _ = bvh_forward_kinematics(clip)
    want, _ = forward_kinematics(rot, root, rest)
    order = [clip.skeleton.names.index(n) for n in JOINT_NAMES]
    np.testing.assert_allclose(pos[:, order], want, atol=2e-5)
    text = path.read_text()
    assert "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" in text
    assert "End Site" in text


@needs_data
@pytest.mark.parametrize("name, joints, unit", [
    ("mb_02_01.bvh", 31, "cmu"), ("cc_002_01.bvh", 101, "cm"), ("daz_10_01.bvh", 43, "cm"),
])
def test_real_clips_parse(name, joints, unit):
    index = {r["file"]: r for r in csv.DictReader(open(DATA / "index.csv"))}
    clip = read_bvh(DATA / name, scale="auto")
    assert clip.skeleton.num_joints == joints
    assert clip.num_frames == int(index[name]["frames"])
    assert clip.fps == pytest.approx(float(index[name]["fps"]), rel=1e-3)
    assert guess_scale(read_bvh(DATA / name).skeleton) == UNIT_SCALES[unit]
    pos, _ = bvh_forward_kinematics(clip)
    height = pos[0, :, 1].max() - pos[0, :, 1].min()
    assert 1.3 < height < 2.0  # metres: a standing adult


@needs_data
def test_real_clip_round_trip(tmp_path):
    clip = read_bvh(DATA / "cc_002_01.bvh")
    write_bvh(tmp_path / "x.bvh", clip)
    again = read_bvh(tmp_path / "x.bvh")
    assert again.skeleton.names == clip.skeleton.names
    np.testing.assert_allclose(again.channels, clip.channels, atol=1e-6)
    np.testing.assert_allclose(bvh_forward_kinematics(again)[0], bvh_forward_kinematics(clip)[0],
                               atol=1e-4)
