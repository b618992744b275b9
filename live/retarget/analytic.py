"""Local joint rotations from joint positions, and rotation-copy retargeting between bodies.

Every rest skeleton is in the canonical T-pose (../shared/CONVENTIONS.md), so a joint's rest
global rotation is the identity and its rest bone directions are world directions. For each joint
with children we find the global rotation G_j that takes its rest bone direction(s) to the
observed one(s); local rotations are then L_j = G_parent^T G_j.

* pelvis: frame from two directions, the hip line (left_hip - right_hip) and spine1 - pelvis.
* spine3: frame from the collar line (left_collar - right_collar) and neck - spine3.
* every other joint with one child: the shortest-arc swing of its bone, relative to its parent
  (no twist of its own: spine1/spine2 twist is carried by spine3, the head follows the torso's
  twist, feet follow the shin), except the limb roots:
* hips and shoulders: the twist about the thigh / upper arm is taken from the plane of the limb
  (hip-knee-ankle, shoulder-elbow-wrist) so that the knee / elbow is a hinge about its rest axis
  (knee +x, left elbow -y, right elbow +y). When the limb is nearly straight (bend < ~5 deg) the
  plane is undefined and the previous frame's twist is kept, blended in up to a bend of ~15 deg.
* leaves (feet, head, wrists) have no children: their twist is not observable from positions,
  they get the identity (they inherit their parent's frame).

Forward kinematics of the result on the same rest skeleton reproduces the input joints exactly
when the input came from that skeleton; twist that positions cannot see is not recovered.
A frame is solved on plain floats (live/core/vec3.py): the pelvis and spine3 frames need no
parent, then every swing joint after its parent; on one joint's 3x3 matrices numpy's per-call
overhead was most of the cost (0.15 against 0.7 ms per frame, benchmarks/bench_retarget.py).
Batches run frame after frame (the limb twists carry over), their local rotations in one batch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from live.core import vec3 as v3
from live.core.errors import UserInputError
from live.core.kinematics import local_matrices
from live.core.rotations import matrix_to_quat
from live.core.skeleton import (
    BONES,
    CHILDREN,
    JOINT_INDEX,
    LEAVES,
    NUM_JOINTS,
    PARENTS,
    joints_from_offsets,
    pelvis_height,
    rest_offsets,
)
from live.core.vec3 import Mat
from live.retarget.ik import cross, dot, normalize

_J = JOINT_INDEX
#: Limb chains whose middle joint is a hinge: (root, middle, end, rest hinge axis).
LIMBS: tuple[tuple[int, int, int, tuple[float, float, float]], ...] = (
    (_J["left_hip"], _J["left_knee"], _J["left_ankle"], (1.0, 0.0, 0.0)),
    (_J["right_hip"], _J["right_knee"], _J["right_ankle"], (1.0, 0.0, 0.0)),
    (_J["left_shoulder"], _J["left_elbow"], _J["left_wrist"], (0.0, -1.0, 0.0)),
    (_J["right_shoulder"], _J["right_elbow"], _J["right_wrist"], (0.0, 1.0, 0.0)),
)
_LIMB_OF = {int(limb[0]): k for k, limb in enumerate(LIMBS)}
_LIMB_IDX_F = [tuple(int(i) for i in limb[:3]) for limb in LIMBS]  # (root, middle, end) per limb
#: Bend angles (radians) between which the limb plane takes over from the previous twist.
STRAIGHT_LO = float(np.deg2rad(5.0))
STRAIGHT_HI = float(np.deg2rad(15.0))

# Joints posed from a frame of two child directions: joint -> (a_from, a_to, b_from, b_to).
_FRAMED = {
    _J["pelvis"]: (_J["right_hip"], _J["left_hip"], _J["pelvis"], _J["spine1"]),
    _J["spine3"]: (_J["right_collar"], _J["left_collar"], _J["spine3"], _J["neck"]),
}


@dataclass(frozen=True)
class RestInfo:
    """Per-rest-skeleton constants of the solver (computed once per body; the per-frame ones as
    plain floats, which ``_solve_frame`` runs on)."""

    rest_joints: np.ndarray  # (22, 3)
    offsets: np.ndarray  # (22, 3) offsets from the parent (root keeps its position)
    frames_t: dict  # framed joint -> its rest frame of two child directions, transposed (3 rows)
    swing_units: list  # (22,) rest unit direction to the only child (zero elsewhere), rows
    # Per limb: (rest unit direction d0 of the upper bone, rest hinge axis h orthogonal to it,
    # d0 x h, rest lower-bone direction . h (what a hinge about h keeps)).
    limbs: list

    @classmethod
    def of(cls, rest_joints: np.ndarray) -> RestInfo:
        rest = np.asarray(rest_joints, dtype=np.float64)
        if rest.shape != (NUM_JOINTS, 3):
            raise UserInputError(f"rest joints must be (22, 3), got {rest.shape}")
        if pelvis_height(rest) <= 0:
            raise UserInputError("rest skeleton pelvis must be above the floor (y > 0)")
        frames_t = {j: tuple(zip(*v3.frame((rest[a1] - rest[a0]).tolist(), (rest[b1] - rest[b0]).tolist())))
                    for j, (a0, a1, b0, b1) in _FRAMED.items()}
        swing = np.zeros((NUM_JOINTS, 3))
        for j in range(NUM_JOINTS):
            if len(CHILDREN[j]) == 1:
                swing[j] = normalize(rest[CHILDREN[j][0]] - rest[j])
        dirs = normalize(np.array([rest[m] - rest[r] for r, m, _, _ in LIMBS]))
        hinges = np.array([h for *_, h in LIMBS], dtype=np.float64)
        hinges = normalize(hinges - np.sum(hinges * dirs, axis=-1, keepdims=True) * dirs)
        lower = normalize(np.array([rest[e] - rest[m] for _, m, e, _ in LIMBS]))
        limbs = list(zip(dirs.tolist(), hinges.tolist(), cross(dirs, hinges).tolist(), dot(lower, hinges).tolist()))
        # (Units normalised twice, as the solver's rotation between them always did.)
        return cls(rest, rest_offsets(rest), frames_t, normalize(swing).tolist(), limbs)


def _limb_twist(x: list, g: Mat, limb: tuple, consts: tuple) -> tuple[float, float]:
    """Twist angle about a limb's upper bone that makes its middle joint a hinge, and its weight.

    x: one frame's joints (22 rows of floats); g: the upper bone's global rotation without twist;
    limb: (root, middle, end) joints; consts: (rest upper direction d0, hinge h, d0 x h, rest c).
    Returns (angle, weight in [0, 1], 0 where the limb is too straight for its plane to be known).

    A hinge about h keeps the lower bone's component along h at its rest value c = e0 . h. With
    the lower bone s seen in the untwisted upper frame, x = s . h, y = s . (d0 x h), twisting by
    theta gives x cos(theta) + y sin(theta) = c, so theta = atan2(y, x) + acos(c / r),
    r = |(x, y)| (the + branch bends the hinge the natural way). This stays exact for a rest limb
    that is not perfectly straight, where the plain limb-plane normal is off by many degrees.
    """
    r, m, e = limb
    _, hinge, binormal, rest_c = consts
    lower = v3.unit(v3.sub(x[e], x[m]))
    bend = math.acos(v3.clamp(v3.dot(v3.unit(v3.sub(x[m], x[r])), lower)))
    s_loc = v3.mtv(g, lower)
    hx, hy = v3.dot(s_loc, hinge), v3.dot(s_loc, binormal)
    radius = math.sqrt(hx * hx + hy * hy)
    angle = math.atan2(hy, hx) + math.acos(v3.clamp(rest_c / max(radius, 1e-12)))
    weight = v3.clamp((bend - STRAIGHT_LO) / (STRAIGHT_HI - STRAIGHT_LO), 0.0, 1.0)
    return angle, weight


def _swing_order() -> tuple[tuple[int, int, int, int], ...]:
    """(joint, parent, child, limb or -1) of every joint posed by the swing of its one bone,
    parents before children (framed joints need no parent, so they come before everything)."""
    order, done = [], set(_FRAMED)
    while len(done) < NUM_JOINTS:
        for j in range(1, NUM_JOINTS):
            if j not in done and PARENTS[j] in done:
                done.add(j)
                if len(CHILDREN[j]) == 1:
                    order.append((j, int(PARENTS[j]), CHILDREN[j][0], _LIMB_OF.get(j, -1)))
    return tuple(order)


_SWING = _swing_order()
_LEAVES = tuple((j, int(PARENTS[j])) for j in LEAVES)  # (leaf, parent)


def _solve_frame(x: list, info: RestInfo, twist: list) -> list:
    """Global rotations (22 matrices, rows of floats) of one frame's joints x (22 rows of
    floats); ``twist`` (4 floats, the limbs' twists of the frame before) is updated in place."""
    glob: list = [None] * NUM_JOINTS
    for j, (a0, a1, b0, b1) in _FRAMED.items():
        glob[j] = v3.mm(v3.frame(v3.sub(x[a1], x[a0]), v3.sub(x[b1], x[b0])), info.frames_t[j])
    for j, p, c, k in _SWING:
        gp = glob[p]
        g = v3.mm(gp, v3.between_units(info.swing_units[j], v3.mtv(gp, v3.sub(x[c], x[j]))))
        if k >= 0:
            # The plane's twist where the limb is bent, the previous frame's where it is straight.
            angle, weight = _limb_twist(x, g, _LIMB_IDX_F[k], info.limbs[k])
            twist[k] = v3.wrap_angle(twist[k] + weight * v3.wrap_angle(angle - twist[k]))
            g = v3.mm(g, v3.axis_angle(info.limbs[k][0], twist[k]))
        glob[j] = g
    for j, p in _LEAVES:
        glob[j] = glob[p]
    return glob


def solve_globals(
    joints: np.ndarray, info: RestInfo, twist: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global and local rotation matrices of posed joints (the core of local_rotations_from_joints).

    joints (N, 22, 3) float64; twist (4,) the limb twists of the frame before (online state).
    Returns (global (N, 22, 3, 3), local (N, 22, 3, 3), twist (4,) of the last frame). Frames are
    solved one after the other on plain floats (the twists carry over), locals in one batch.
    """
    prev = [0.0] * len(LIMBS) if twist is None else [float(t) for t in twist]
    glob = np.array([_solve_frame(x, info, prev) for x in np.asarray(joints, np.float64).tolist()])
    glob = glob.reshape(len(joints), NUM_JOINTS, 3, 3)
    return glob, local_matrices(glob), np.array(prev)


def local_rotations_from_joints(joints: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
    """Local rotations relative to the canonical T-pose from world joint positions.

    joints: T x 22 x 3 (any leading shape) world metres; rest_joints: 22 x 3 T-pose of the same
    body. Returns T x 22 x 4 quaternions (w, x, y, z). The root position is joints[..., 0, :].
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape[-2:] != (NUM_JOINTS, 3):
        raise UserInputError(f"joints must be (..., 22, 3), got {joints.shape}")
    lead = joints.shape[:-2]
    _, loc, _ = solve_globals(joints.reshape(-1, NUM_JOINTS, 3), RestInfo.of(rest_joints))
    return matrix_to_quat(loc).reshape(lead + (NUM_JOINTS, 4))


def leg_ratio(source_rest: np.ndarray, target_rest: np.ndarray) -> float:
    """Target rest pelvis height over the source's: the root-translation scale between bodies."""
    return pelvis_height(target_rest) / pelvis_height(source_rest)


def retarget(
    rotations: np.ndarray, root: np.ndarray, source_rest: np.ndarray, target_rest: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move a motion from body A (source_rest) to body B (target_rest), by convention.

    rotations T x 22 x 4 are copied (they mean the same pose on any canonical body); root T x 3
    is scaled by the leg-length ratio about the world origin, horizontally and vertically, so the
    stride and the pelvis height fit the new legs. Returns (rotations, root_target).
    """
    ratio = leg_ratio(source_rest, target_rest)
    return np.array(rotations, dtype=np.float64, copy=True), np.asarray(root, dtype=np.float64) * ratio


_BONE_ENDS = (np.array([p for p, _ in BONES]), np.array([c for _, c in BONES]))


def estimate_rest_joints(joints: np.ndarray, template: np.ndarray | None = None) -> np.ndarray:
    """A T-pose rest skeleton (22 x 3) for a performer seen only as posed joints (T x 22 x 3).

    Bone lengths are the per-bone medians over frames; bone directions come from ``template``
    (default: the body library's mean T-pose, live.body.library.mean_rest_template, or the straight-leg
    live.core.skeleton.default_rest_joints() without a library; the straight legs make real performers
    6-10 % tall). The feet are put on the floor at the template's foot height, scaled by the leg
    length found.
    """
    from live.body.library import mean_rest_template
    from live.core.skeleton import default_rest_joints

    joints = np.asarray(joints, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
    if template is None:
        template = mean_rest_template()
    tpl = np.asarray(default_rest_joints() if template is None else template, dtype=np.float64)
    tpl_off = rest_offsets(tpl)
    parents, children = _BONE_ENDS
    lengths = np.median(np.linalg.norm(joints[:, children] - joints[:, parents], axis=-1), axis=0)
    dirs = normalize(tpl_off)
    offsets = np.zeros((NUM_JOINTS, 3))  # pelvis at the origin
    offsets[children] = dirs[children] * lengths[:, None]
    rest = joints_from_offsets(offsets)
    feet = [_J["left_ankle"], _J["right_ankle"], _J["left_foot"], _J["right_foot"]]
    drop = -rest[feet, 1].min()
    # The template's lowest foot joint sits above the floor by a fraction of its leg length.
    tpl_clear = tpl[feet, 1].min() / tpl[0, 1]
    rest[:, 1] += drop / (1.0 - tpl_clear)
    return rest.astype(np.float32)

