"""Depth + IMU fusion that is never worse than its parts: each bone weighed by what is known of it.

Per depth frame (``Fuser.update``), with the suit's orientations aligned to the frame's time:

1. The suit's segment rotations are corrected by the rotation filters of
   ``live.imu.fusion_filters``: a shared heading (the calibration frame's yaw in the world) and,
   per sensor, a mounting rotation and a heading drift, all learnt from the depth bones while
   depth sees them (Kalman filters: their variances say how well each bone is known).
2. Every bone gets a direction from the suit (measured segments; joints without a sensor are
   interpolated, ``live.imu.suit_skeleton.fill_globals``) with a standard deviation: the filter's
   for measured segments, a wide one for interpolated joints (a spine bent unevenly), and a
   length learnt from depth.
3. The joints are the least-squares fit of both sources: each depth joint pulls with its
   confidence over the depth noise, each suit bone with its variance. A linear 22-joint system
   (the same for x, y and z), solved twice: depth joints far from the first fit (beyond what
   their noise and the bone's explain: a limb the regressor lost but still reports) are
   down-weighted (Cauchy) in the second. A bone the suit knows well carries a limb depth lost;
   a bone it knows badly follows depth. With the depth image at hand, a limb the image does not
   show where the suit puts it (``live.imu.fusion_visibility``: hidden, out of view, covered) is
   left to the suit: the regressor keeps reporting such an arm, with confidence, where it guesses.
4. Without depth (no person in the frame) the suit poses the skeleton at a root moved by foot
   odometry from the last fused one. A depth skeleton whose body as a whole lies more than
   ``root_jump`` from where the suit moved it since the last frame is not used either (a
   performer half out of view, read half a metre too low as they leave it), unless it stays
   there for ``root_jump_hold_s``: then the suit's root had drifted, and depth places it again.

Before the heading is known (the first depth frame) and for bones the suit does not measure,
the result is the depth skeleton's; as the filters converge, the suit's share grows.
"""

from __future__ import annotations

import numpy as np

from live.core.frames import DepthFrame, SkeletonFrame
from live.core.heading import wrap_angle, yaw_between, yaw_quat
from live.core.kinematics import joints_from_global_quats, local_rotations
from live.core.rotations import quat_multiply, quat_rotate
from live.core.skeleton import BONES, CHILDREN, JOINT_INDEX, NUM_JOINTS, joints_from_offsets, rest_offsets
from live.core.timing import frame_interval_s, seconds_between
from live.imu.calibration import Calibration
from live.imu.fusion_filters import HeadingFilter, SensorFilter, majority_angle
from live.imu.fusion_visibility import seen_fraction
from live.imu.suit_skeleton import FootOdometry, SuitPose, fill_globals

_PARENT = np.array([p for p, _ in BONES])
_CHILD = np.array([c for _, c in BONES])
#: Bones inside a limb (from a hip or shoulder down): the depth image is asked whether it shows them.
_LIMB_BONES = np.array([b for b, (p, _) in enumerate(BONES) if p in
                        {JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("hip", "knee", "ankle", "shoulder", "elbow")}])
#: Incidence of the 21 bones: (21, 22), +1 at the child, -1 at the parent.
INCIDENCE = np.zeros((len(BONES), NUM_JOINTS))
INCIDENCE[np.arange(len(BONES)), _CHILD] = 1.0
INCIDENCE[np.arange(len(BONES)), _PARENT] = -1.0


#: Each joint against the pelvis: (21, 22), +1 at joint j (1..21), -1 at the pelvis.
STAR = np.zeros((NUM_JOINTS - 1, NUM_JOINTS))
STAR[np.arange(NUM_JOINTS - 1), np.arange(1, NUM_JOINTS)] = 1.0
STAR[:, 0] = -1.0


def solve_joints(depth: np.ndarray, depth_weight: np.ndarray, bones: np.ndarray, bone_weight: np.ndarray,
                 prior: np.ndarray, prior_weight: float, relative: np.ndarray | None = None,
                 relative_weight: np.ndarray | None = None) -> np.ndarray:
    """Joints (22, 3) minimising sum_j w_j |x_j - depth_j|^2 + sum_b v_b |x_c - x_p - bone_b|^2
    + prior_weight |x - prior|^2 + sum_j u_j |x_j - x_pelvis - relative_j|^2. depth (22, 3),
    depth_weight (22,), bones (21, 3) in BONES order, bone_weight (21,), prior (22, 3), relative
    (22, 3) and relative_weight (22,) (row 0 unused). One 22 x 22 matrix for the three axes."""
    A = INCIDENCE.T @ (bone_weight[:, None] * INCIDENCE)
    A[np.diag_indices(NUM_JOINTS)] += depth_weight + prior_weight
    rhs = depth_weight[:, None] * depth + INCIDENCE.T @ (bone_weight[:, None] * bones) + prior_weight * prior
    if relative is not None and relative_weight is not None:
        u = relative_weight[1:]
        A += STAR.T @ (u[:, None] * STAR)
        rhs += STAR.T @ (u[:, None] * relative[1:])
    return np.linalg.solve(A, rhs)


#: Segments whose bones keep the template's direction (only their length is learnt): the limbs,
#: whose sensors' mounting filter turns their bones instead. Torso bones (pelvis to hips and
#: spine, chest to neck and collars, ...) are learnt in full in their parent's frame: bodies
#: differ there more than any mounting error.
LIMB_SEGMENTS = frozenset(JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right")
                          for j in ("hip", "knee", "ankle", "foot", "shoulder", "elbow", "wrist"))


class RestShape:
    """The performer's rest bone offsets (each in its parent's frame) learnt from depth: a running
    confidence-weighted mean of G_parent^-1 (x_child - x_parent) for torso bones, of the length
    alone for limb bones (template direction), shrunk toward the template scaled by the median
    length ratio until ``frames_full`` frames of evidence."""

    def __init__(self, template: np.ndarray, frames_full: float = 30.0):
        self.template = np.asarray(template, np.float64)
        tpl = rest_offsets(self.template)[_CHILD]
        self.tpl_len = np.linalg.norm(tpl, axis=-1)
        self.tpl_unit = tpl / np.maximum(self.tpl_len[:, None], 1e-9)
        self.limb = np.array([p in LIMB_SEGMENTS for p in _PARENT])
        self.sum = np.zeros((len(BONES), 3))
        self.len_sum = np.zeros(len(BONES))
        self.weight = np.zeros(len(BONES))
        self.frames_full = frames_full

    def add(self, joints: np.ndarray, glob: np.ndarray, weight: np.ndarray) -> None:
        w = np.sqrt(weight[_CHILD] * weight[_PARENT])
        d = joints[_CHILD] - joints[_PARENT]
        self.sum += w[:, None] * quat_rotate(glob[_PARENT] * np.array([1.0, -1.0, -1.0, -1.0]), d)
        self.len_sum += w * np.linalg.norm(d, axis=-1)
        self.weight += w

    def offsets(self) -> np.ndarray:
        """(22, 3) rest offsets (row 0 zero)."""
        seen = self.weight > 1e-6
        wt = np.maximum(self.weight, 1e-9)
        length = np.where(seen, self.len_sum / wt, self.tpl_len)
        long = seen & (self.tpl_len > 0.05)
        scale = float(np.median(length[long] / self.tpl_len[long])) if long.any() else 1.0
        base = scale * self.tpl_len[:, None] * self.tpl_unit
        learnt = np.where(self.limb[:, None], self.tpl_unit * length[:, None], self.sum / wt[:, None])
        trust = np.clip(self.weight / self.frames_full, 0.0, 1.0)[:, None]
        out = np.zeros((NUM_JOINTS, 3))
        out[_CHILD] = np.where(seen[:, None], trust * learnt + (1.0 - trust) * base, base)
        return out

    def variance(self, torso_std: float = 0.3, limb_std: float = 0.05) -> np.ndarray:
        """(21,) how uncertain each bone's offset still is (m^2): a fraction of its length
        (torso_std of torso bones' template offsets, limb_std of limb lengths) shrinking as
        evidence comes in."""
        frac = np.where(self.limb, limb_std, torso_std) * self.tpl_len
        return frac ** 2 * self.frames_full / (self.frames_full + self.weight)

    def rest_joints(self) -> np.ndarray:
        """(22, 3) T-pose from the learnt offsets, the lowest foot joint as high as the template's."""
        rest = joints_from_offsets(self.offsets())
        feet = [7, 8, 10, 11]
        rest[:, 1] += self.template[feet, 1].min() - rest[feet, 1].min()
        return rest


#: The depth skeleton's noise per joint and axis (m) where the depth supports the joint
#: (confidence > 0): RMS errors of the skeleton stage on sessions of the fusion's tuning clips and
#: bodies (CMU subject 7 on adult_male_average and short_male; ``python -m
#: research.imu_fusion_eval --tune`` re-measures them on its own cases, 0.011-0.037 m behind the
#: regressor they were measured with). Behind the shipped regressor the tuning cases measure
#: 0.019-0.052 m; with those the tuning cases come out no better (fused 29.4 mm either way, lost
#: limbs 37.7 against 37.9 mm), so these stay.
DEPTH_STD = np.array([0.017, 0.020, 0.020, 0.026, 0.024, 0.020, 0.029, 0.024, 0.020, 0.031, 0.028, 0.023,
                      0.021, 0.024, 0.023, 0.021, 0.023, 0.020, 0.025, 0.029, 0.040, 0.039])
#: Joints inside the body: the depth never supports them (confidence ~0), and they are no worse
#: for it.
INNER = np.array([JOINT_INDEX[n] for n in ("spine1", "spine2", "spine3")])


def depth_variance(confidence: np.ndarray, joints: np.ndarray, unsupported: float = 6.0,
                   min_conf: float = 0.0) -> np.ndarray:
    """(22,) variance (m^2, per axis) of each depth joint: DEPTH_STD, times ``unsupported`` where
    the depth does not support it (confidence <= min_conf: hidden, out of the image) except inner
    joints; infinite for non-finite joints."""
    std = DEPTH_STD * np.where(np.asarray(confidence) > min_conf, 1.0, unsupported)
    std[INNER] = DEPTH_STD[INNER]
    return np.where(np.all(np.isfinite(joints), axis=-1), std ** 2, np.inf)


def default_template(rest_joints: np.ndarray) -> np.ndarray:
    """The body library's mean T-pose (real bodies' bone directions) at the pelvis height of
    ``rest_joints``; ``rest_joints`` itself without a library."""
    from live.body.library import mean_rest_template
    from live.core.skeleton import pelvis_height

    tpl = mean_rest_template()
    rest = np.asarray(rest_joints, np.float64)
    return rest if tpl is None else np.asarray(tpl, np.float64) * pelvis_height(rest)


def _joint_var(bone_weight: np.ndarray) -> np.ndarray:
    """(22,) position variance a joint inherits from the suit: its own bone's, for the pelvis the
    best-known of its bones'."""
    var = np.full(NUM_JOINTS, np.inf)
    inv = np.where(bone_weight > 0, 1.0 / np.maximum(bone_weight, 1e-30), np.inf)
    var[_CHILD] = inv
    var[0] = inv[_PARENT == 0].min()
    return var


class Fuser:
    """Fuses aligned suit orientations with depth skeletons (see module doc).

    unsupported: how much noisier a depth joint without depth support is (``depth_variance``); interp_std: direction std (rad) of a
    bone whose parent has no sensor (interpolated or following its parent); imu_std: of a measured
    segment's bones beyond what its filter knows (jitter, skin motion); length_std: of a bone's
    length (m); robust: the Cauchy scale, in standard
    deviations, of the second solve; shape_rate (m/sqrt(s)): how fast the body's shape (each
    joint against the pelvis) may drift from where the last frame and the suit's motion since put
    it (a Kalman prediction; the depth joints are its measurements); correlation: how many frames one depth measurement is
    worth less than independent ones (the depth stage's errors last: its temporal model, a pose
    it misreads for a while), dividing what the filters learn from each; interp_window / interp_prior: frames the suit variance of
    bones without a sensor is averaged over, and how many the interp_std guess counts for; gate / clear_frames: when a limb's depth joints are taken for
    lost and found again (``_lost_limbs``); seen_min / seen_radius: a limb bone of which the depth
    image shows less than this share within this distance (m) where the suit puts it is unseen
    (``_unseen_limbs``: its depth joint pulls nothing and teaches nothing); heading_votes: how many
    first heading measurements vote on where it starts; root_jump (m) / root_jump_hold_s: a depth
    skeleton that far from the suit's prediction as a whole is left out, for up to that long
    (``_jumped``); filter options: ``heading`` (HeadingFilter) and
    ``sensor`` (SensorFilter) keyword dicts."""

    def __init__(self, calibration: Calibration, *, template: np.ndarray | None = None, unsupported: float = 6.0,
                 interp_std: float = np.radians(20.0), imu_std: float = np.radians(2.0), length_std: float = 0.01,
                 robust: float = 3.0, learn_conf: float = 0.5, gate: float = 2.5, clear_frames: int = 15,
                 correlation: float = 8.0, shape_rate: float = 0.1,
                 interp_window: int = 60, interp_prior: int = 10, seen_min: float = 0.3, seen_radius: float = 0.04,
                 heading_votes: int = 15, root_jump: float = 0.3, root_jump_hold_s: float = 0.5,
                 heading: dict | None = None, sensor: dict | None = None):
        self.cal = calibration
        self.template = default_template(calibration.rest_joints) if template is None else np.asarray(template, np.float64)
        self.S = len(calibration.sensors)
        self.row = {int(j): i for i, j in enumerate(calibration.joints)}
        from live.imu.suit_skeleton import ChainPlan

        self.plan = ChainPlan.of(calibration.joints)
        self._filter_options = (dict(heading or {}), dict(sensor or {}))
        self.heading_votes = heading_votes
        self._heading_votes: list[float] = []
        self.interp_std, self.length_std, self.interp_prior = interp_std, length_std, interp_prior
        self._start_learning()
        self.unsupported, self.imu_std = unsupported, imu_std
        self.robust, self.learn_conf = robust, learn_conf
        self.gate, self.clear_frames, self.correlation = gate, clear_frames, correlation
        self.shape_rate, self.shape_start_s = shape_rate, 1.0
        self._rel_prev = np.zeros((NUM_JOINTS, 3))
        self.last_bones: tuple[np.ndarray, np.ndarray] | None = None  # suit bone vectors and weights
        self.interp_window = interp_window
        self.odometry = FootOdometry(self.template)
        self._root: np.ndarray | None = None
        self._odo_prev: np.ndarray | None = None
        self._last_t: int | None = None
        self.frames = 0
        self.seen_min, self.seen_radius = seen_min, seen_radius
        self.root_jump, self.root_jump_hold_s = root_jump, root_jump_hold_s
        self._jump_since: int | None = None  # when depth started to disagree with the suit's root
        self.counters = {"depth_frames": 0, "suit_only_frames": 0, "outliers": 0, "lost_joint_frames": 0,
                         "unseen_joint_frames": 0, "restarts": 0, "root_jumps": 0}
        # The bones the suit measures: (sensor row, its segment joint, the child joint, the bone's
        # index in BONES, the bone's number among its segment's).
        pairs = [(i, int(j), c, c - 1, n) for i, j in enumerate(calibration.joints)
                 for n, c in enumerate(CHILDREN[int(j)])]
        self._rows, self._joint, self._child, self._bone, self._slot = (
            np.array([p[k] for p in pairs], np.int64).reshape(-1) for k in range(5))

    def _start_learning(self) -> None:
        """Everything learnt from depth, as before the first frame: the filters, the performer's
        shape, the lost limbs."""
        self.heading = HeadingFilter(**self._filter_options[0])
        free = np.array([int(j) in LIMB_SEGMENTS for j in self.cal.joints])
        self.sensors = SensorFilter(self.S, mount_free=free, **self._filter_options[1])
        self.shape = RestShape(self.template)
        tpl_len = np.linalg.norm(rest_offsets(self.template)[_CHILD], axis=-1)
        self._interp_var = (self.interp_std * tpl_len) ** 2 + self.length_std ** 2
        self._interp_n = np.full(len(BONES), float(self.interp_prior))
        self._lost = np.zeros(NUM_JOINTS, bool)
        self._agree = np.zeros(NUM_JOINTS, np.int64)
        self._shape: np.ndarray | None = None  # last fused joints against the pelvis
        self._shape_var = np.full(NUM_JOINTS, np.inf)

    # -- pieces ---------------------------------------------------------------------------------
    def rest_joints(self) -> np.ndarray:
        return self.shape.rest_joints()

    def _segments(self, quats: np.ndarray) -> np.ndarray:
        """Calibrated segment rotations with the shared heading (S, 4), before the sensor filter."""
        g = self.cal.segment_globals(quats)
        return quat_multiply(yaw_quat(np.full(self.S, self.heading.yaw)), g)

    def _heading_update(self, seg: np.ndarray, offs: np.ndarray, x: np.ndarray, var: np.ndarray) -> None:
        """The yaw turning the suit's measured bones onto the depth bones, into the heading filter."""
        if not len(self._rows):
            return
        corrected = self.sensors.correct(seg)
        pred = quat_rotate(corrected[self._rows], offs[self._child])
        obs = x[self._child] - x[self._joint]
        angle, evidence = yaw_between(pred, obs, 1.0 / (var[self._child] + var[self._joint]))
        if evidence < 1e-3:
            return
        if len(self._heading_votes) < self.heading_votes:
            # The first measurements vote on the start: the heading starts from the first one, and
            # starts again, with all learnt so far forgotten, if the others outvote it (a first
            # depth skeleton mirrored left-right would otherwise lock the heading half a turn off,
            # with torso offsets learnt to match).
            self._heading_votes.append(float(wrap_angle(self.heading.yaw + angle)))
            start = majority_angle(self._heading_votes, np.radians(20.0))
            if self.heading.variance is not None and abs(float(wrap_angle(start - self.heading.yaw))) > np.radians(20.0):
                self._start_learning()
                self.counters["restarts"] += 1
            if self.heading.variance is None:
                self.heading.update(float(wrap_angle(start - self.heading.yaw)), 1.0 / evidence)
                return
        self.heading.update(angle, 1.0 / evidence)

    def _sensor_updates(self, seg: np.ndarray, offs: np.ndarray, x: np.ndarray, var: np.ndarray) -> None:
        k = np.flatnonzero(np.isfinite(var[self._child]) & np.isfinite(var[self._joint]))
        if not len(k):
            return
        child, joint = self._child[k], self._joint[k]
        u, H = self.sensors.jacobian(seg, self._rows[k], offs[child])
        length = np.linalg.norm(offs[child], axis=-1)
        dir_var = self.correlation * (var[child] + var[joint]) / np.maximum(length, 0.05) ** 2
        self.sensors.update(H, u, self._rows[k], x[child] - x[joint], dir_var, self._slot[k])

    def _bones(self, glob: np.ndarray, seg: np.ndarray, offs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Suit bone vectors (21, 3) and their weights (21,) (1 / variance in m^2)."""
        vec = quat_rotate(glob[_PARENT], offs[_CHILD])
        if self.heading.variance is None:
            return vec, np.zeros(len(BONES))
        length = np.linalg.norm(offs[_CHILD], axis=-1)
        var = self._interp_var.copy()  # bones of joints without a sensor: as found against depth
        if len(self._rows):
            b = self._bone
            _, H = self.sensors.jacobian(seg, self._rows, offs[self._child])
            dir_var = self.sensors.direction_var(H, self._rows) + self.imu_std ** 2
            dir_var += self.heading.variance * (1.0 - (vec[b, 1] / np.maximum(length[b], 1e-9)) ** 2)
            var[b] = dir_var * length[b] ** 2 + self.length_std ** 2 + self.shape.variance()[b]
        return vec, 1.0 / var

    def _learn_interp_var(self, x: np.ndarray, var: np.ndarray, vec: np.ndarray) -> None:
        """Running estimate of each bone's suit variance from its residual against depth (what
        the residual's spread leaves once the depth's own noise is taken out), used for bones
        whose parent has no sensor: how far interpolation is off depends on the motion."""
        ok = np.isfinite(var[_PARENT]) & np.isfinite(var[_CHILD])
        r = (x[_CHILD] - x[_PARENT]) - vec
        sample = np.maximum(np.sum(r * r, axis=-1) / 3.0 - var[_PARENT] - var[_CHILD], self.length_std ** 2)
        self._interp_n = np.where(ok, np.minimum(self._interp_n + 1, self.interp_window), self._interp_n)
        gain = np.where(ok, 1.0 / np.maximum(self._interp_n, 1), 0.0)
        self._interp_var = np.where(ok, self._interp_var + gain * (np.where(ok, sample, 0.0) - self._interp_var),
                                    self._interp_var)

    def _unseen_limbs(self, x: np.ndarray, vec: np.ndarray, image: DepthFrame, camera_to_world: np.ndarray
                      ) -> np.ndarray:
        """(22,) limb joints whose bone the depth image does not show where the suit puts it: the
        limb drawn from the depth's hip or shoulder along the suit's bones, each bone's share of
        points with depth within ``seen_radius`` below ``seen_min`` (live.imu.fusion_visibility)."""
        pos = x.copy()
        for b in _LIMB_BONES:  # BONES order: a parent is placed before its children
            pos[_CHILD[b]] = pos[_PARENT[b]] + vec[b]
        seen = seen_fraction(image, camera_to_world, pos[_PARENT[_LIMB_BONES]], pos[_CHILD[_LIMB_BONES]],
                             radius=self.seen_radius)
        out = np.zeros(NUM_JOINTS, bool)
        out[_CHILD[_LIMB_BONES]] = seen < self.seen_min
        self.counters["unseen_joint_frames"] += int(out.sum())
        return out

    # -- one frame ------------------------------------------------------------------------------
    def _lost_limbs(self, x: np.ndarray, var: np.ndarray, vec: np.ndarray, bone_w: np.ndarray,
                    unseen: np.ndarray) -> np.ndarray:
        """(22,) depth joints of limbs the depth lost: the bone leading to the joint is farther
        from the suit's than both their variances explain (``gate`` standard deviations, three
        degrees of freedom), or the joint hangs below such a one. A joint stays lost until its
        bone has been within the gate, and seen in the depth image, for ``clear_frames`` frames
        in a row."""
        for b, (p, c) in enumerate(BONES):
            if c not in LIMB_SEGMENTS:
                continue
            if bone_w[b] <= 0 or unseen[c] or not (np.isfinite(var[p]) and np.isfinite(var[c])):
                self._agree[c] = 0
                continue
            r = (x[c] - x[p]) - vec[b]
            d2 = float(r @ r) / (1.0 / bone_w[b] + var[p] + var[c])
            if d2 > self.gate ** 2:
                self._lost[c] = True
                self._agree[c] = 0
            else:
                self._agree[c] += 1
                if self._agree[c] >= self.clear_frames:
                    self._lost[c] = False
            if self._lost[p] and p in LIMB_SEGMENTS:
                self._lost[c] = True
        self.counters["lost_joint_frames"] += int(self._lost.sum())
        return self._lost.copy()

    def _jumped(self, x: np.ndarray, var: np.ndarray, prior: np.ndarray, t_ns: int) -> bool:
        """Whether the depth joints x as a whole (the per-axis median of their offsets from the
        suit's prediction ``prior``, over the joints depth supports) lie more than root_jump
        away, for less than root_jump_hold_s so far (counted in ``root_jumps``). Only once a
        root has been fused and the heading is known: before, the suit's prediction is not
        placed in the world."""
        if self._root is None or self.heading.variance is None:
            return False
        ok = np.isfinite(var)
        offset = np.median((x - prior)[ok], axis=0) if ok.any() else np.zeros(3)
        if float(np.linalg.norm(offset)) <= self.root_jump:
            self._jump_since = None
            return False
        if self._jump_since is None:
            self._jump_since = t_ns
        if seconds_between(self._jump_since, t_ns) >= self.root_jump_hold_s:
            return False  # depth has said so for long enough: the suit's root drifted
        self.counters["root_jumps"] += 1
        return True

    def update(self, quats: np.ndarray, t_ns: int, depth: SkeletonFrame | None, image: DepthFrame | None = None,
               camera_to_world: np.ndarray | None = None) -> tuple[SuitPose, np.ndarray] | None:
        """quats (S, 4) at t_ns -> (fused pose, confidence (22,)). depth None: the suit alone,
        with what the filters learnt so far (None before any depth frame: nothing says where
        the performer is yet). image: the depth frame the skeleton was estimated from, and
        camera_to_world the one its joints were solved in: limb joints the image does not show
        where the suit puts them count as unsupported by depth and teach the filters nothing."""
        dt = frame_interval_s(30) if self._last_t is None else max(seconds_between(self._last_t, t_ns), 1e-4)
        self._last_t = t_ns
        self.heading.predict(dt)
        self.sensors.predict(dt)
        x = var = None
        if depth is not None:
            x = np.asarray(depth.joints, np.float64)
            var = depth_variance(depth.confidence, x, self.unsupported)
            if not np.isfinite(var).any():
                x = var = None
            else:
                x = np.where(np.isfinite(x), x, 0.0)
        if x is None and self.heading.variance is None:
            return None  # nothing says where the performer is or faces yet
        offs = self.shape.offsets()
        seg = self._segments(quats)
        glob = fill_globals(self.sensors.correct(seg), self.plan)
        vec, bone_w = self._bones(glob, seg, offs)
        unseen = np.zeros(NUM_JOINTS, bool)
        if x is not None:
            if image is not None and camera_to_world is not None and self.heading.variance is not None:
                unseen = self._unseen_limbs(x, vec, image, camera_to_world)
                var = np.where(unseen, np.inf, var)
            # Tested as if supported: a guess the depth does not support must agree with the suit.
            base = np.where(np.isfinite(var), DEPTH_STD ** 2, np.inf)
            var = np.where(self._lost_limbs(x, base, vec, bone_w, unseen), np.inf, var)
            self._heading_update(seg, offs, x, var)
            seg = self._segments(quats)
            glob = fill_globals(self.sensors.correct(seg), self.plan)
            vec, bone_w = self._bones(glob, seg, offs)
        rel = joints_from_global_quats(glob, np.zeros(3), offs)
        odo = self.odometry.update(rel)
        step = np.zeros(3) if self._odo_prev is None else odo - self._odo_prev
        self._odo_prev = odo
        predicted_root = odo if self._root is None else self._root + step
        prior = rel + predicted_root
        # The body's shape (joints against the pelvis) a frame ago, moved as the suit says since.
        relative, rel_w = None, None
        if self._shape is not None:
            self._shape_var += self.shape_rate ** 2 * dt
            relative = self._shape + (rel - self._rel_prev)
            rel_w = 1.0 / self._shape_var
        self._rel_prev = rel
        if x is not None and self._jumped(x, var, prior, t_ns):
            x = None
        if x is None:
            joints = solve_joints(np.zeros((NUM_JOINTS, 3)), np.zeros(NUM_JOINTS), vec, bone_w, prior, 1.0,
                                  relative, rel_w)
            self.counters["suit_only_frames"] += 1
        else:
            depth_w = np.where(np.isfinite(var), 1.0 / var, 0.0)
            joints = solve_joints(x, depth_w, vec, bone_w, prior, 1e-6, relative, rel_w)
            # Second solve: depth joints the suit's bones cannot explain lose their pull (the
            # residual against its own noise and the uncertainty of the bone leading to it).
            r2 = np.sum((joints - x) ** 2, axis=-1) / (var + _joint_var(bone_w))
            keep = 1.0 / (1.0 + r2 / self.robust ** 2)
            self.counters["outliers"] += int(np.sum(keep < 0.5))
            joints = solve_joints(x, depth_w * keep, vec, bone_w, prior, 1e-6, relative, rel_w)
            seen = depth_w * keep
            info = np.where(seen > 0, 1.0 / (1.0 / np.maximum(seen, 1e-30) + 1.0 / max(seen[0], 1e-30)), 0.0)
            self._shape_var = 1.0 / (1.0 / self._shape_var + info)
            learn_var = np.where((keep >= self.learn_conf) & ~unseen, var, np.inf)
            if self.heading.variance is not None:  # the suit's bones mean nothing before its heading
                self._learn_interp_var(x, learn_var, vec)
                self._sensor_updates(seg, offs, x, learn_var)
                self.shape.add(x, glob, np.minimum(0.025 ** 2 / learn_var, 1.0))
            self.counters["depth_frames"] += 1
        self._root = joints[0].copy()
        if self._shape is None and x is not None:
            self._shape_var = np.full(NUM_JOINTS, self.shape_rate ** 2 * self.shape_start_s)
        if self._shape is not None or x is not None:
            self._shape = joints - joints[0]
        self.last_bones = (vec, bone_w)
        self.frames += 1
        out_conf = np.ones(NUM_JOINTS) if x is not None else np.full(NUM_JOINTS, 0.8)
        return SuitPose(root=joints[0].copy(), local=local_rotations(glob), glob=glob, joints=joints), out_conf


__all__ = ["Fuser", "RestShape", "LIMB_SEGMENTS", "solve_joints", "INCIDENCE"]
