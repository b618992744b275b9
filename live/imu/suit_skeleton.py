"""IMU suit -> the 22 local rotations and world joints of the performer's rest skeleton.

Pure pieces: ``fill_globals`` completes the segment rotations the suit measures into all 22
global rotations (joints without a sensor between two measured ones share the relative
rotation, e.g. the spine between pelvis and chest; others follow their parent or a given local
rotation such as the depth skeleton's); local rotations and joints then come from
live.core.kinematics. Stateful: ``FootOdometry`` puts the root where the stance foot stays
planted when no camera gives it, and ``SuitSolver`` chains calibration -> heading -> rotations
-> FK.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.heading import yaw_quat
from live.core.kinematics import joints_from_global_quats, local_rotations
from live.core.rotations import quat_conjugate, quat_identity, quat_multiply, quat_normalize, quat_slerp
from live.core.skeleton import CHILDREN, JOINT_INDEX, LEVELS, NUM_JOINTS, PARENTS, rest_offsets
from live.imu.calibration import Calibration
from live.imu.heading_guard import HeadingGuard

#: How much of a measured relative rotation an unmeasured joint takes, relative to the measured
#: joint's own share (1.0). Collars move far less than the shoulders they carry.
CHAIN_WEIGHT: dict[int, float] = {JOINT_INDEX["left_collar"]: 0.4, JOINT_INDEX["right_collar"]: 0.4}

_FOOT_JOINTS = np.array([JOINT_INDEX[n] for n in ("left_ankle", "left_foot", "right_ankle", "right_foot")])
_SIDE = np.array([0, 0, 1, 1])


@dataclass(frozen=True)
class ChainPlan:
    """How each of the 22 global rotations is obtained from S measured segments.

    source (22,) row of the measured segment or -1; anchor (22,) for interpolated joints the
    ancestor whose rotation the chain starts from, else -1; target (22,) the measured row that
    ends the chain, else -1; share (22,) the fraction of the anchor->target rotation applied."""

    source: np.ndarray
    anchor: np.ndarray
    target: np.ndarray
    share: np.ndarray

    @classmethod
    def of(cls, sensor_joints: np.ndarray) -> ChainPlan:
        row = {int(j): i for i, j in enumerate(np.asarray(sensor_joints))}
        source = np.array([row.get(j, -1) for j in range(NUM_JOINTS)])
        anchor = np.full(NUM_JOINTS, -1)
        target = np.full(NUM_JOINTS, -1)
        share = np.zeros(NUM_JOINTS)
        for j in range(NUM_JOINTS):
            if source[j] >= 0 or anchor[j] >= 0 or PARENTS[j] < 0:
                continue
            chain = [j]
            while chain[-1] not in row and len(CHILDREN[chain[-1]]) == 1:
                chain.append(CHILDREN[chain[-1]][0])
            if chain[-1] not in row:
                continue  # no measured segment below: follows its parent
            weights = np.array([CHAIN_WEIGHT.get(k, 1.0) for k in chain[:-1]] + [1.0])
            cum = np.cumsum(weights) / weights.sum()
            for k, c in zip(chain[:-1], cum[:-1]):
                anchor[k], target[k], share[k] = PARENTS[j], row[chain[-1]], c
        return cls(source=source, anchor=anchor, target=target, share=share)


def fill_globals(segment_globals: np.ndarray, plan: ChainPlan, fallback_local: np.ndarray | None = None,
                 root_global: np.ndarray | None = None) -> np.ndarray:
    """Measured segment rotations (..., S, 4) -> all 22 global rotations (..., 22, 4).

    fallback_local (..., 22, 4): local rotations for joints with neither a sensor nor a measured
    joint below them (default identity: they follow their parent). root_global (..., 4): the
    pelvis rotation when the suit has no pelvis sensor (default identity). Joints are filled one
    tree level at a time, each level in one batch."""
    seg = np.asarray(segment_globals, dtype=np.float64)
    lead = seg.shape[:-2]
    out = quat_identity(lead + (NUM_JOINTS,))
    measured = plan.source >= 0
    out[..., measured, :] = seg[..., plan.source[measured], :]
    if not measured[0] and root_global is not None:
        out[..., 0, :] = root_global
    for level in LEVELS[1:]:
        chain = level[(plan.source[level] < 0) & (plan.anchor[level] >= 0)]
        if len(chain):
            a = out[..., plan.anchor[chain], :]
            rel = quat_multiply(quat_conjugate(a), seg[..., plan.target[chain], :])
            frac = quat_slerp(quat_identity(rel.shape[:-1]), rel, plan.share[chain])
            out[..., chain, :] = quat_multiply(a, frac)
        follow = level[(plan.source[level] < 0) & (plan.anchor[level] < 0)]
        if len(follow):
            par = out[..., PARENTS[follow], :]
            out[..., follow, :] = par if fallback_local is None else quat_multiply(par, fallback_local[..., follow, :])
    return quat_normalize(out)


def foot_clearance(rest_joints: np.ndarray) -> np.ndarray:
    """(4,) height above the floor of ankles and feet when standing (from the T-pose)."""
    return np.asarray(rest_joints, np.float64)[_FOOT_JOINTS, 1]


class FootOdometry:
    """Root position from foot contacts (no camera): the lower foot is planted; the root moves
    so that it stays where it is, and the lowest foot joint rests on the floor.

    ``update(rel)`` takes the joints relative to the pelvis (22, 3) and returns the root (3,).
    start: the first root position; its height then also fixes the floor (a performer who starts
    on a known spot). hysteresis: metres the other foot must be lower by to take over as the
    stance foot."""

    def __init__(self, rest_joints: np.ndarray, start: np.ndarray | None = None, floor: float = 0.0,
                 hysteresis: float = 0.01):
        self.clear = foot_clearance(rest_joints) + floor
        self.root = None if start is None else np.asarray(start, np.float64).copy()
        self.hysteresis = hysteresis
        self.stance = 0
        self._lift = 0.0
        self._prev: np.ndarray | None = None

    def update(self, rel: np.ndarray) -> np.ndarray:
        feet = np.asarray(rel, np.float64)[_FOOT_JOINTS] - np.array([0.0, 1.0, 0.0]) * self.clear[:, None]
        low = np.array([feet[_SIDE == s, 1].min() for s in (0, 1)])
        planted = self.stance  # the foot that was on the ground since the last frame
        if low[1 - self.stance] < low[self.stance] - self.hysteresis:
            self.stance = 1 - self.stance
        y = -low.min()
        if self._prev is None and self.root is not None:
            self._lift = self.root[1] - y
        y += self._lift
        if self.root is None:
            self.root = np.array([0.0, y, 0.0])
        elif self._prev is not None:
            k = _SIDE == planted
            step = (self._prev[k] - feet[k]).mean(axis=0)
            self.root = self.root + np.array([step[0], 0.0, step[2]])
        self.root[1] = y
        self._prev = feet
        return self.root.copy()


@dataclass
class SuitPose:
    """One solved pose: root (3,), local (22, 4) and global (22, 4) rotations, joints (22, 3)."""

    root: np.ndarray
    local: np.ndarray
    glob: np.ndarray
    joints: np.ndarray


class SuitSolver:
    """Sensor orientations -> pose on the performer's rest skeleton.

    world_yaw: heading of the calibration frame in the output world (radians; 0 = the performer
    faced +z during calibration). start: root position of the first frame (default: x = z = 0,
    feet on the floor)."""

    def __init__(self, calibration: Calibration, rest_joints: np.ndarray | None = None, *,
                 world_yaw: float = 0.0, start: np.ndarray | None = None, floor: float = 0.0,
                 heading_guard: bool = True):
        self.cal = calibration
        self.guard = HeadingGuard(calibration.joints) if heading_guard else None
        self._last_t: int | None = None
        self.rest_joints = np.asarray(calibration.rest_joints if rest_joints is None else rest_joints, np.float64)
        self.plan = ChainPlan.of(calibration.joints)
        self.world_yaw = float(world_yaw)
        self.odometry = FootOdometry(self.rest_joints, start=start, floor=floor)
        self._has_pelvis = bool(np.any(calibration.joints == 0))

    def segment_globals(self, quats: np.ndarray, yaw_correction: np.ndarray | None = None) -> np.ndarray:
        """Sensor orientations (S, 4) -> world segment rotations (S, 4), headings corrected by
        world_yaw plus a per-sensor yaw_correction (S,) radians (drift, from fusion)."""
        g = self.cal.segment_globals(quats)
        yaw = self.world_yaw + (0.0 if yaw_correction is None else np.asarray(yaw_correction))
        return quat_multiply(yaw_quat(np.broadcast_to(yaw, g.shape[:-1])), g)

    def solve(self, quats: np.ndarray, *, yaw_correction: np.ndarray | None = None,
              fallback_local: np.ndarray | None = None, root: np.ndarray | None = None,
              rest_joints: np.ndarray | None = None, t_ns: int | None = None) -> SuitPose:
        """quats (S, 4) in calibration (layout) order -> SuitPose. root: the pelvis position when
        known (depth); else foot odometry. rest_joints: override the skeleton (fusion). t_ns: the
        sample's time (the heading guard's time step; default 1/30 s)."""
        if rest_joints is not None:
            self.rest_joints = np.asarray(rest_joints, np.float64)
        seg = self.segment_globals(quats, yaw_correction)
        if self.guard is not None:
            dt = 1.0 / 30.0 if t_ns is None or self._last_t is None else max((t_ns - self._last_t) * 1e-9, 1e-4)
            self._last_t = t_ns
            self.guard.update(seg, dt)
            seg = self.guard.apply(seg)
        root_g = None if self._has_pelvis or fallback_local is None else fallback_local[0]
        glob = fill_globals(seg, self.plan, fallback_local, root_global=root_g)
        local = local_rotations(glob)
        rel = joints_from_global_quats(glob, np.zeros(3), rest_offsets(self.rest_joints))
        odo = self.odometry.update(rel)
        r = odo if root is None else np.asarray(root, np.float64)
        return SuitPose(root=r, local=local, glob=glob, joints=rel + r)
