"""Simulated IMU suit: the IMU model's physics, layouts, and the pty device end to end
(decode(read from the pty) == what was sent, damage, configuration, unplug / replug)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
import serial

from drivers.serial_source import SerialSource, decode_packet_bytes
from drivers.xbus_stream import XbusConfigurator, XbusParser
from live.core.errors import DeviceError, FormatError
from live.core.kinematics import global_rotations
from live.core.rotations import quat_conjugate, quat_from_axis_angle, quat_multiply, quat_rotate
from live.core.skeleton import JOINT_INDEX
from live.imu.layout import DEFAULT_LAYOUT, load_suit_layout, parse_suit_layout
from sim.imu_device import DEVICE_ID_BASE, SimulatedSuit
from sim.imu_model import GRAVITY, ImuNoise, SimpleMotion, random_smooth_motion, simulate_imus

WAIT = 15.0
LAYOUT = load_suit_layout().as_dict()
MOTION = random_smooth_motion(60, fps=60.0, seed=3)


def same_rotations(a, b, tol):
    d = np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))
    return float(d.max()) < tol


# ----------------------------------------------------------------------------- layouts / model

def test_default_layout_has_15_sensors():
    assert len(LAYOUT) == 15 and LAYOUT[1] == JOINT_INDEX["pelvis"]
    assert LAYOUT[5] == JOINT_INDEX["left_elbow"] and LAYOUT[15] == JOINT_INDEX["right_ankle"]
    assert json.loads(DEFAULT_LAYOUT.read_text())["sensors"]["2"] == "spine3"


def test_layout_aliases_and_errors(tmp_path):
    assert parse_suit_layout({"sensors": {"7": "left_forearm", "1": "chest"}}).as_dict() == {
        1: JOINT_INDEX["spine3"], 7: JOINT_INDEX["left_elbow"]}
    for bad in ({}, {"sensors": {}}, {"sensors": {"x": "pelvis"}}, {"sensors": {"1": "tail"}}):
        with pytest.raises(FormatError):
            parse_suit_layout(bad)
    p = tmp_path / "bad.json"
    p.write_text("{nope")
    with pytest.raises(FormatError, match="bad.json"):
        load_suit_layout(p)


def test_model_orientations_rates_and_specific_force():
    mount = quat_from_axis_angle(np.random.default_rng(0).normal(size=(15, 3)))
    track = simulate_imus(MOTION, LAYOUT, mounting=mount)
    glob = global_rotations(MOTION.rotations)
    expected = quat_multiply(glob[:, list(LAYOUT.values())], mount[None])
    assert same_rotations(track.quats, expected, 1e-12)
    # Integrating the body rates forward reproduces the next orientation.
    dt = 1.0 / MOTION.fps
    step = quat_multiply(track.quats[:-1], quat_from_axis_angle(track.gyro[:-1] * dt))
    assert same_rotations(step, track.quats[1:], 1e-9)
    # At rest the accelerometer reads +g along the world up axis, in the sensor frame.
    still = SimpleMotion(fps=60.0, rotations=np.broadcast_to(MOTION.rotations[:1], (10, 22, 4)),
                         root=np.broadcast_to(MOTION.root[:1], (10, 3)), rest_joints=MOTION.rest_joints)
    rest = simulate_imus(still, LAYOUT, mounting=mount)
    up = quat_rotate(rest.quats, rest.acc)
    np.testing.assert_allclose(up, np.broadcast_to([0, GRAVITY, 0], up.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(rest.mag, axis=-1), 1.0)
    np.testing.assert_allclose(rest.gyro, 0.0, atol=1e-12)


def test_model_heading_drift_is_about_world_up():
    track = simulate_imus(MOTION, LAYOUT, noise=ImuNoise(yaw_drift_std=0.05), seed=1)
    rel = quat_multiply(track.quats, quat_conjugate(track.true_quats))
    np.testing.assert_allclose(rel[..., [1, 3]], 0.0, atol=1e-12)
    assert np.abs(rel[-1, :, 2]).max() > 1e-4  # it did drift
    noisy = simulate_imus(MOTION, LAYOUT, noise=ImuNoise(gyro_std=0.01, acc_std=0.1), seed=1)
    assert np.std(noisy.gyro - track.gyro) == pytest.approx(0.01, rel=0.1)


# ----------------------------------------------------------------------------- device on a pty

def stream_all(suit: SimulatedSuit, protocol: str, **source_options):
    """Read a non-looping fast suit to its end through SerialSource; returns the packets."""
    packets = []
    arrived = threading.Event()

    def emit(p):
        packets.append(p)
        arrived.set()

    src = SerialSource(suit.port, protocol, **source_options)
    src.start(emit)
    assert src.connected.wait(WAIT)
    suit.resume()
    assert suit.finished.wait(WAIT)  # set once every byte has been written to the pty
    while src.counters["bytes"] < suit.counters["bytes"]:
        arrived.clear()
        assert arrived.wait(WAIT)
    src.stop()
    assert src.error is None and src.counters["bytes"] == suit.counters["bytes"]
    return packets, src


def keyed(packets):
    out = {}
    for p in packets:
        for s, c, q in zip(p.sensors, p.counter, p.quats):
            out[(int(s), int(c))] = q
    return out


@pytest.mark.parametrize("options", [
    dict(protocol="xbus"),
    dict(protocol="xbus", xbus_addressing="device_id", orientation="matrix", precision="fp1220", coord="ned",
         extras=("acc", "gyro", "mag")),
    dict(protocol="lines", extras=("acc", "gyro")),
    dict(protocol="lines", line_format="json", extras=("acc", "gyro", "mag")),
])
def test_decoded_equals_sent(options):
    with SimulatedSuit(MOTION, rate_hz=120, realtime=False, loop=False, paused=True, **options) as suit:
        packets, src = stream_all(suit, options["protocol"])
        truth = suit.truth()
    assert len(truth.step) == suit.total_steps * 15
    got = keyed(packets)
    assert set(got) == set(zip(truth.sensor.tolist(), truth.counter.tolist()))
    sent = np.array([truth.quat[i] for i in range(len(truth.step))])
    dec = np.array([got[(s, c)] for s, c in zip(truth.sensor.tolist(), truth.counter.tolist())])
    assert same_rotations(dec, sent, 2e-6)
    if options.get("xbus_addressing") == "device_id":
        assert truth.sensor.min() == DEVICE_ID_BASE + 1
    if "acc" in options.get("extras", ()):
        # Records arrive in the order sent; a read that ended mid-record carries none.
        acc = np.concatenate([p.acc for p in packets if len(p.sensors)])
        frame = suit.frame_of_step(truth.step)
        sensor_index = np.tile(np.arange(15), suit.total_steps)
        np.testing.assert_allclose(acc, suit.track.acc[frame, sensor_index], atol=1e-5)
    # The recorded raw bytes replay to the same records, in float64 for Xbus.
    replay = decode_packet_bytes([p.raw for p in packets], options["protocol"])
    assert sum(len(p.sensors) for p in replay) == len(truth.step)
    if options["protocol"] == "xbus":
        parser = XbusParser()
        full = [s for p in packets for s in parser.feed(p.raw)]
        tol = 5e-6 if options.get("precision") == "fp1220" else 1e-7
        assert same_rotations(np.array([s.quat for s in full]), sent, tol)


@pytest.mark.parametrize("protocol", ["xbus", "lines"])
def test_damaged_bytes_lose_only_damaged_records(protocol):
    with SimulatedSuit(MOTION, protocol, rate_hz=120, realtime=False, loop=False, paused=True,
                       corrupt_prob=0.05, drop_prob=0.05, seed=4) as suit:
        packets, src = stream_all(suit, protocol, parser_options=(
            {"require_checksum": True} if protocol == "lines" else None))
        truth = suit.truth()
    keys = list(zip(truth.sensor.tolist(), truth.counter.tolist()))
    intact = {k for k, ok in zip(keys, truth.intact) if ok}
    assert 0 < len(keys) - len(intact) < 0.2 * len(keys)
    got = keyed(packets)
    # A frame cut short at the very end waits for bytes that never come: flush with silence.
    for r in src.parser.feed(bytes(4096)):
        got[(r.sensor, r.counter)] = r.quat
    assert set(got) == intact
    c = src.counters
    errors = c.get("bad_checksum", 0) + c.get("bad_length", 0) + c.get("bad_lines", 0)
    assert errors > 0


def test_configurator_against_the_simulated_mti():
    with SimulatedSuit(MOTION, "xbus", rate_hz=100, realtime=True, loop=True) as suit:
        port = serial.serial_for_url(suit.port, timeout=0.05)
        try:
            conf = XbusConfigurator(port, timeout=2.0)
            with pytest.raises(DeviceError, match="refused"):  # only valid in config mode
                conf.set_output_configuration([(0x2010, 100)])
            acked = conf.configure(50, orientation="euler", precision="fp1632", coord="nwu")
        finally:
            port.close()
        assert acked[2] == (0x203A, 50)
        assert (suit.orientation, suit.precision, suit.coord, suit.rate_hz) == ("euler", "fp1632", "nwu", 50.0)
    with SimulatedSuit(MOTION, "lines") as silent:  # a text suit never acknowledges
        port = serial.serial_for_url(silent.port, timeout=0.05)
        try:
            with pytest.raises(DeviceError, match="no acknowledgement"):
                XbusConfigurator(port, timeout=0.2).go_to_config()
        finally:
            port.close()


def test_source_configures_on_connect_and_survives_unplug():
    baseline = threading.active_count()
    seen = {"before": 0, "after": 0}
    resumed = threading.Event()
    first = threading.Event()
    replugged = threading.Event()
    with SimulatedSuit(MOTION, "xbus", rate_hz=200, realtime=True, loop=True) as suit:
        src = SerialSource(suit.port, "xbus", backoff_start=0.02,
                           xbus_config={"rate_hz": 100, "orientation": "quat", "precision": "float64"})

        def emit(p):
            key = "after" if replugged.is_set() else "before"
            seen[key] += len(p.sensors)
            if seen["before"] >= 150:
                first.set()
            if seen["after"] >= 150:
                resumed.set()

        thread = src.start(emit)
        assert first.wait(WAIT)
        assert suit.precision == "float64" and suit.rate_hz == 100
        suit.close()  # unplug: the reader's pty goes away, the port path disappears
        suit.reopen()  # replug: a new pty behind the same path (the output config persists)
        replugged.set()
        assert resumed.wait(WAIT)
        c = src.counters
        assert c["gaps"] >= 1 and c["connects"] >= 2 and src.gaps[0][1] is not None
        assert suit.counters["commands"] >= 6  # configured again on reconnect
        src.stop(timeout=1.0)
        assert not thread.is_alive()
    assert threading.active_count() == baseline


def test_real_cmu_clip_through_the_pty():
    clip = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bvh" / "cc_001_01.bvh"
    if not clip.exists():
        pytest.skip("the shared CMU clips are not beside the checkout")
    from live.motion.rig_mapping import load_motion

    m = load_motion(clip)
    motion = SimpleMotion(fps=m.fps, rotations=m.rotations[:90], root=m.root[:90], rest_joints=m.rest_joints)
    with SimulatedSuit(motion, "xbus", rate_hz=60, realtime=False, loop=False, paused=True,
                       extras=("acc",)) as suit:
        packets, _ = stream_all(suit, "xbus")
        truth = suit.truth()
    dec = np.concatenate([p.quats for p in packets if len(p.sensors)])
    assert same_rotations(dec, truth.quat, 2e-6)
    # Sensor 1 is the pelvis: its decoded orientation is the clip's root rotation times the mount.
    pelvis = truth.sensor == 1
    frames = suit.frame_of_step(truth.step[pelvis])
    expected = quat_multiply(m.rotations[frames, 0], suit.track.mounting[0])
    assert same_rotations(dec[pelvis], expected, 2e-6)
