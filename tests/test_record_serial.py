"""A real Xsens byte stream (MTData2 frames as an MTi sends them, from the simulated suit on a
pty) goes through `livecap record --source serial:PTY:xbus` and `livecap export` into the
decoded IMU file with exact values."""

import numpy as np

from live.app.cli import main
from live.core.rotations import quat_canonical
from sim.imu_device import SimulatedSuit
from sim.imu_model import random_smooth_motion


def test_record_then_export_gives_the_exact_values_sent(tmp_path):
    motion = random_smooth_motion(120, fps=60.0, seed=5)
    session = tmp_path / "suit.mcap"
    with SimulatedSuit(motion, protocol="xbus", rate_hz=100, realtime=True, loop=True) as suit:
        assert main(["record", "--source", f"serial:{suit.port}:xbus", "--out", str(session),
                     "--seconds", "1.5", "--quiet"]) == 0
        truth = suit.truth()
    assert main(["export", str(session), "--out", str(tmp_path / "exp")]) == 0
    raw = np.load(tmp_path / "exp" / "serial_serial.npz")
    assert raw["offsets"][-1] == len(raw["data"]) > 0
    imu = np.load(tmp_path / "exp" / "imu_serial.npz")
    assert len(imu["t_ns"]) > 100 and np.all(np.diff(imu["t_ns"]) >= 0)
    sent = {(int(s), int(c)): q for s, c, q in zip(truth.sensor, truth.counter, truth.quat)}
    matched = 0
    for s, c, q in zip(imu["sensor"], imu["counter"], imu["quat"]):
        want = sent.get((int(s), int(c)))
        assert want is not None
        # float32 on the wire: equal to the sent quaternion within float32 rounding.
        np.testing.assert_allclose(quat_canonical(q), quat_canonical(want), atol=2e-7)
        matched += 1
    assert matched == len(imu["t_ns"])
