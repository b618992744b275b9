"""Depth + IMU fusion: limb rotations from the suit, root, heading and proportions from depth.

Per depth frame (``Fuser.update``), with the suit's orientations aligned to the frame's time:
- heading: each sensor's heading drift (a yaw about world up) is the yaw that best turns the
  bones its segment carries (as the IMU predicts them) onto the depth skeleton's bones, weighted
  by depth confidence and horizontal length, and low-pass filtered (drift is slow, depth noise
  is not);
- rotations: measured segments from the IMUs (they do not care about occlusion); joints without
  a sensor are interpolated (suit_skeleton) and then swung toward the depth bone direction by a
  filtered correction;
- proportions: the rest offset of every bone is the confidence-weighted mean of
  G_parent^-1 (x_child - x_parent) over frames (full 3D, not only the length), frozen after
  ``rest_frames``;
- root: the IMU foot odometry step, pulled toward the depth pelvis (a complementary filter).
"""

from __future__ import annotations

import numpy as np

from live.core.frames import SkeletonFrame
from live.core.heading import wrap_angle, yaw_between
from live.core.kinematics import joints_from_global_quats, local_rotations
from live.core.rotations import quat_between, quat_identity, quat_multiply, quat_rotate, quat_slerp
from live.core.skeleton import ANCESTORS, CHILDREN, JOINT_INDEX, NUM_JOINTS, PARENTS, joints_from_offsets, rest_offsets
from live.core.timing import frame_interval_s, seconds_between
from live.imu.calibration import Calibration
from live.imu.suit_skeleton import SuitPose, SuitSolver, fill_globals
from live.retarget.analytic import estimate_rest_joints

#: Bones whose rest direction is kept from the template and only the length is learnt: the
#: limbs, where a heading error of the parent's sensor would otherwise be baked into the offset
#: (and then never seen again by the heading filter).
LENGTH_ONLY = np.array([JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right")
                        for j in ("knee", "ankle", "foot", "shoulder", "elbow", "wrist")])


class RestEstimator:
    """Running confidence-weighted mean of rest bone offsets in the parent's frame (torso) and
    of bone lengths (limbs, see LENGTH_ONLY)."""

    def __init__(self, template: np.ndarray):
        self.template = np.asarray(template, np.float64)
        self.sum = np.zeros((NUM_JOINTS, 3))
        self.length = np.zeros(NUM_JOINTS)
        self.weight = np.zeros(NUM_JOINTS)
        self.frames = 0

    def add(self, joints: np.ndarray, glob: np.ndarray, conf: np.ndarray) -> None:
        child = np.arange(1, NUM_JOINTS)
        par = PARENTS[1:]
        w = conf[child] * conf[par]
        d = joints[child] - joints[par]
        inv = glob[par] * np.array([1.0, -1.0, -1.0, -1.0])
        self.sum[1:] += w[:, None] * quat_rotate(inv, d)
        self.length[1:] += w * np.linalg.norm(d, axis=-1)
        self.weight[1:] += w
        self.frames += 1

    def rest_joints(self, trust: float = 1.0) -> np.ndarray:
        """(22, 3) T-pose skeleton: the template scaled by the median length ratio, moved toward
        the mean offsets by ``trust`` (1: the offsets as measured; 0: only the overall scale,
        robust to per-joint depth bias); feet on the floor."""
        tpl = rest_offsets(self.template)
        seen = self.weight > 1e-6
        w = np.maximum(self.weight, 1e-9)
        off = np.where(seen[:, None], self.sum / w[:, None], tpl)
        lengths = self.length[LENGTH_ONLY] / w[LENGTH_ONLY]
        unit = tpl[LENGTH_ONLY] / np.maximum(np.linalg.norm(tpl[LENGTH_ONLY], axis=-1, keepdims=True), 1e-9)
        off[LENGTH_ONLY] = np.where(seen[LENGTH_ONLY, None], unit * lengths[:, None], tpl[LENGTH_ONLY])
        tl = np.linalg.norm(tpl[1:], axis=-1)
        ratio = np.linalg.norm(off[1:], axis=-1) / np.maximum(tl, 1e-9)
        scale = float(np.median(ratio[seen[1:] & (tl > 0.05)])) if np.any(seen[1:] & (tl > 0.05)) else 1.0
        off = scale * tpl + trust * (off - scale * tpl)
        off[0] = 0.0  # pelvis at the origin
        rest = joints_from_offsets(off)
        low = rest[[7, 8, 10, 11], 1].min()
        tpl_low = self.template[[7, 8, 10, 11], 1].min()
        rest[:, 1] += -low + tpl_low
        return rest


class Fuser:
    """Fuses aligned suit orientations with depth skeletons (see module doc).

    heading_tau_s: time constant of the shared heading filter; drift_tau_s: of each sensor's
    own drift, learnt only from bones whose horizontal evidence (m^2) reaches drift_evidence
    (None: off, the default: a sensor's mounting-heading error then leaks into its drift
    estimate and costs more than the slow drift it removes on sessions of minutes); swing_alpha: per-frame gain of the
    correction of unmeasured joints; root_gain: pull of the depth pelvis on the root per frame;
    rest_frames: frames averaged into the bone offsets before they are frozen; min_conf: depth
    joints below it are ignored."""

    def __init__(self, calibration: Calibration, *, heading_tau_s: float = 1.0, drift_tau_s: float | None = None,
                 drift_evidence: float = 0.03, swing_alpha: float = 0.15,
                 root_gain: float = 0.45, rest_frames: int = 300, rest_trust: float = 0.5, warmup_frames: int = 10, min_conf: float = 0.3):
        self.cal = calibration
        self.solver = SuitSolver(calibration, calibration.rest_joints)
        self.plan = self.solver.plan
        self.S = len(calibration.sensors)
        self.yaw = np.zeros(self.S)
        self.common_yaw = 0.0
        self.drift = np.zeros(self.S)
        self.heading_tau_s = heading_tau_s
        self.drift_tau_s = float("inf") if drift_tau_s is None else float(drift_tau_s)
        self.drift_evidence = drift_evidence
        self.swing_alpha = swing_alpha
        self.root_gain = root_gain
        self.rest_frames = rest_frames
        self.rest_trust = rest_trust
        self.warmup_frames = warmup_frames
        self.min_conf = min_conf
        self.rest = RestEstimator(calibration.rest_joints)
        self._seen: list[np.ndarray] = []
        self._swing = quat_identity((NUM_JOINTS,))
        self._root: np.ndarray | None = None
        self._odo_prev: np.ndarray | None = None
        self._last_t: int | None = None
        self.frames = 0
        # Sensor rows whose segment carries bones (heading observable) / leaves (borrow).
        row = {int(j): i for i, j in enumerate(calibration.joints)}
        self._borrow = np.arange(self.S)
        for i, j in enumerate(calibration.joints):
            if not CHILDREN[int(j)]:
                a = next((a for a in ANCESTORS[int(j)] if a in row), -1)
                self._borrow[i] = row[a] if a >= 0 else i
        self._free = [j for j in range(1, NUM_JOINTS) if self.plan.source[j] < 0 and CHILDREN[j]]
        self._needs_depth_locals = any(self.plan.anchor[j] < 0 for j in self._free)

    def rest_joints(self) -> np.ndarray:
        if self.rest.frames >= self.warmup_frames:
            return self.rest.rest_joints(self.rest_trust)
        if self._seen:
            return estimate_rest_joints(np.stack(self._seen), self.cal.rest_joints).astype(np.float64)
        return np.asarray(self.cal.rest_joints, np.float64)

    def _update_heading(self, seg: np.ndarray, x: np.ndarray, conf: np.ndarray, offs: np.ndarray,
                        dt: float) -> None:
        """Sensors share one world heading up to slow per-sensor drift: the shared part comes
        from every bone pooled (fast), each sensor's drift only from its own well-observed
        (horizontal) bones (slow)."""
        sums = np.zeros((self.S, 2))
        for i, j in enumerate(self.cal.joints):
            kids = list(CHILDREN[int(j)])
            if not kids:
                continue
            pred = quat_rotate(seg[i], offs[kids])
            obs = x[kids] - x[int(j)]
            w = conf[kids] * conf[int(j)] * (conf[kids] >= self.min_conf) * (conf[int(j)] >= self.min_conf)
            angle, evidence = yaw_between(pred, obs, w)
            sums[i] = evidence * np.sin(angle), evidence * np.cos(angle)
        total = sums.sum(axis=0)
        if np.hypot(*total) < 1e-3:
            return
        common = float(np.arctan2(total[0], total[1]))
        gain = max(1.0 / (self.frames + 1), 1.0 - np.exp(-dt / self.heading_tau_s))
        self.common_yaw = float(wrap_angle(self.common_yaw + gain * common))
        evidence = np.hypot(sums[:, 0], sums[:, 1])
        own = np.arctan2(sums[:, 0], sums[:, 1])
        trust = np.clip(evidence / self.drift_evidence, 0.0, 1.0) ** 2
        drift_gain = (1.0 - np.exp(-dt / self.drift_tau_s)) * trust
        self.drift = wrap_angle(self.drift + drift_gain * wrap_angle(own - common))
        self.yaw = wrap_angle(self.common_yaw + self.drift)

    def _swing_correct(self, glob: np.ndarray, x: np.ndarray, conf: np.ndarray, offs: np.ndarray) -> np.ndarray:
        """Turn each unmeasured joint by its filtered correction toward the depth bone."""
        for j in self._free:
            kids = list(CHILDREN[j])
            w = conf[kids] * conf[j]
            k = kids[int(np.argmax(w))]
            if w.max() >= self.min_conf:
                meas = quat_between(quat_rotate(glob[j], offs[k]), x[k] - x[j])
                self._swing[j] = quat_slerp(self._swing[j], meas, self.swing_alpha * float(w.max()))
            # Only this joint turns: its children keep their own (global) rotations.
            glob[j] = quat_multiply(self._swing[j], glob[j])
        return glob

    def update(self, quats: np.ndarray, t_ns: int, depth: SkeletonFrame | None) -> tuple[SuitPose, np.ndarray]:
        """quats (S, 4) at t_ns -> (fused pose, confidence (22,)). depth None: the suit alone,
        with the heading and proportions learned so far."""
        dt = frame_interval_s(30) if self._last_t is None else max(seconds_between(self._last_t, t_ns), 1e-4)
        self._last_t = t_ns
        rest = self.rest_joints()
        offs = rest_offsets(rest)
        seg = self.solver.segment_globals(quats, self.yaw)
        x = conf = None
        if depth is not None:
            x = np.asarray(depth.joints, np.float64)
            conf = np.asarray(depth.confidence, np.float64)
            if len(self._seen) < self.warmup_frames:
                self._seen.append(x)
            self._update_heading(seg, x, conf, offs, dt)
            self.drift = self.drift[self._borrow]
            self.yaw = wrap_angle(self.common_yaw + self.drift)
            seg = self.solver.segment_globals(quats, self.yaw)
        fallback = None
        if x is not None and self._needs_depth_locals:
            from live.retarget.analytic import local_rotations_from_joints

            fallback = local_rotations_from_joints(x, rest)
        glob = fill_globals(seg, self.plan, fallback)
        if x is not None:
            glob = self._swing_correct(glob, x, conf, offs)
        local = local_rotations(glob)
        rel = joints_from_global_quats(glob, np.zeros(3), offs)
        odo = self.solver.odometry.update(rel)
        step = np.zeros(3) if self._odo_prev is None else odo - self._odo_prev
        self._odo_prev = odo
        root = odo if self._root is None else self._root + step
        if x is not None and conf[0] >= self.min_conf:
            k = 1.0 if self._root is None else self.root_gain * conf[0]
            root = root + k * (x[0] - root)
        self._root = root
        if x is not None and self.frames >= self.warmup_frames and self.rest.frames < self.rest_frames:
            self.rest.add(x, glob, conf * (conf >= self.min_conf))
        self.frames += 1
        out_conf = np.ones(NUM_JOINTS)
        if depth is None:
            out_conf *= 0.8
        return SuitPose(root=root, local=local, glob=glob, joints=rel + root), out_conf


__all__ = ["Fuser", "RestEstimator", "LENGTH_ONLY"]
