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
Batch computations run step by step on rotation matrices (four dependency steps: the pelvis and
spine3 frames need no parent, then each swing joint one step after its parent), so one frame
costs a few dozen numpy calls (see benchmarks/bench_retarget.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.errors import UserInputError
from live.retarget.ik import axis_angle_matrix, cross, dot, normalize, rotation_between_units
from live.rotations import matrix_to_quat
from live.skeleton import BONES, CHILDREN, JOINT_INDEX, NUM_JOINTS, PARENTS, pelvis_height, rest_offsets

_J = JOINT_INDEX
#: Limb chains whose middle joint is a hinge: (root, middle, end, rest hinge axis).
LIMBS: tuple[tuple[int, int, int, tuple[float, float, float]], ...] = (
    (_J["left_hip"], _J["left_knee"], _J["left_ankle"], (1.0, 0.0, 0.0)),
    (_J["right_hip"], _J["right_knee"], _J["right_ankle"], (1.0, 0.0, 0.0)),
    (_J["left_shoulder"], _J["left_elbow"], _J["left_wrist"], (0.0, -1.0, 0.0)),
    (_J["right_shoulder"], _J["right_elbow"], _J["right_wrist"], (0.0, 1.0, 0.0)),
)
#: Bend angles (radians) between which the limb plane takes over from the previous twist.
_LIMB_IDX = np.array([limb[:3] for limb in LIMBS], dtype=np.int64)
_LIMB_OF = {int(limb[0]): k for k, limb in enumerate(LIMBS)}
STRAIGHT_LO = np.deg2rad(5.0)
STRAIGHT_HI = np.deg2rad(15.0)

# Joints posed from a frame of two child directions: joint -> (a_from, a_to, b_from, b_to).
_FRAMED = {
    _J["pelvis"]: (_J["right_hip"], _J["left_hip"], _J["pelvis"], _J["spine1"]),
    _J["spine3"]: (_J["right_collar"], _J["left_collar"], _J["spine3"], _J["neck"]),
}


def _depths() -> np.ndarray:
    d = np.zeros(NUM_JOINTS, dtype=np.int64)
    for j in range(1, NUM_JOINTS):
        d[j] = d[PARENTS[j]] + 1
    return d


_DEPTH = _depths()
#: Joint indices per tree level (parents always in an earlier level).
LEVELS: tuple[np.ndarray, ...] = tuple(np.flatnonzero(_DEPTH == k) for k in range(_DEPTH.max() + 1))


def frame_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Orthonormal frames (..., 3, 3) with columns (a, b orthogonalised, a x b) from (..., 3)."""
    e1 = normalize(a)
    e3 = normalize(cross(e1, b))
    out = np.empty(e1.shape + (3,))
    out[..., 0], out[..., 1], out[..., 2] = e1, cross(e3, e1), e3
    return out


@dataclass(frozen=True)
class RestInfo:
    """Per-rest-skeleton constants of the solver (computed once per body)."""

    rest_joints: np.ndarray  # (22, 3)
    offsets: np.ndarray  # (22, 3) offsets from the parent (root keeps its position)
    frames: dict[int, np.ndarray]  # joint -> (3, 3) rest frame of its two child directions
    framed_rest_t: np.ndarray  # (F, 3, 3) those frames transposed, in _FRAMED order
    swing_dirs: np.ndarray  # (22, 3) rest unit direction to the only child (zero elsewhere)
    swing_units: np.ndarray  # swing_dirs normalised again, as rotation_between would per frame
    limb_dirs: np.ndarray  # (4, 3) rest unit direction of each limb's upper bone
    limb_hinges: np.ndarray  # (4, 3) rest hinge axis h, orthogonal to the upper bone
    limb_binormals: np.ndarray  # (4, 3) upper bone x h
    limb_rest_c: np.ndarray  # (4,) rest lower-bone direction . h (kept by a hinge about h)

    @classmethod
    def of(cls, rest_joints: np.ndarray) -> RestInfo:
        rest = np.asarray(rest_joints, dtype=np.float64)
        if rest.shape != (NUM_JOINTS, 3):
            raise UserInputError(f"rest joints must be (22, 3), got {rest.shape}")
        if pelvis_height(rest) <= 0:
            raise UserInputError("rest skeleton pelvis must be above the floor (y > 0)")
        frames = {j: frame_matrix(rest[a1] - rest[a0], rest[b1] - rest[b0]) for j, (a0, a1, b0, b1) in _FRAMED.items()}
        swing = np.zeros((NUM_JOINTS, 3))
        for j in range(NUM_JOINTS):
            if len(CHILDREN[j]) == 1:
                swing[j] = normalize(rest[CHILDREN[j][0]] - rest[j])
        dirs = normalize(np.array([rest[m] - rest[r] for r, m, _, _ in LIMBS]))
        hinges = np.array([h for *_, h in LIMBS], dtype=np.float64)
        hinges = normalize(hinges - np.sum(hinges * dirs, axis=-1, keepdims=True) * dirs)
        lower = normalize(np.array([rest[e] - rest[m] for _, m, e, _ in LIMBS]))
        framed_rest_t = np.stack([frames[j].T for j in _FRAMED])
        return cls(rest, rest_offsets(rest), frames, framed_rest_t, swing, normalize(swing), dirs, hinges,
                   cross(dirs, hinges), dot(lower, hinges))


def _limb_twist(joints: np.ndarray, swing_glob: np.ndarray, info: RestInfo, ks: np.ndarray,
                limb_joints: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None):
    """Twist angles about the limbs' upper bones that make their middle joints hinges.

    joints (N, 22, 3); swing_glob (N, K, 3, 3): the upper bones' global rotations without twist;
    ks (K,) limb numbers (limb_joints: their (root, middle, end) joints, when known). Returns (angle (N, K), weight (N, K) in [0, 1], 0 where the limb is too
    straight for its plane to be known).

    A hinge about h keeps the lower bone's component along h at its rest value c = e0 . h. With
    the lower bone s seen in the untwisted upper frame, x = s . h, y = s . (d0 x h), twisting by
    theta gives x cos(theta) + y sin(theta) = c, so theta = atan2(y, x) + acos(c / r),
    r = |(x, y)| (the + branch bends the hinge the natural way). This stays exact for a rest limb
    that is not perfectly straight, where the plain limb-plane normal is off by many degrees.
    """
    r, m, e = _LIMB_IDX[ks].T if limb_joints is None else limb_joints
    upper = joints[:, m] - joints[:, r]
    lower = normalize(joints[:, e] - joints[:, m])
    bend = np.arccos(np.clip(dot(normalize(upper), lower), -1.0, 1.0))
    s_loc = np.einsum("nkji,nkj->nki", swing_glob, lower)
    x = dot(s_loc, info.limb_hinges[ks])
    y = dot(s_loc, info.limb_binormals[ks])
    radius = np.sqrt(x * x + y * y)
    angle = np.arctan2(y, x) + np.arccos(np.clip(info.limb_rest_c[ks] / np.maximum(radius, 1e-12), -1.0, 1.0))
    weight = np.clip((bend - STRAIGHT_LO) / (STRAIGHT_HI - STRAIGHT_LO), 0.0, 1.0)
    return angle, weight


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class _LevelPlan:
    """What ``solve_globals`` does at one step (index arrays built once, not per frame)."""

    framed: tuple[int, ...]  # joints posed from two child directions (_FRAMED)
    js: np.ndarray  # swing joints
    ps: np.ndarray  # their parents
    cs: np.ndarray  # their children
    sel: np.ndarray  # columns of js that are limb roots
    ks: np.ndarray  # their limb numbers
    limb_joints: tuple[np.ndarray, np.ndarray, np.ndarray]  # (root, middle, end) of those limbs


def _steps() -> np.ndarray:
    """(22,) the step of ``solve_globals`` at which each joint is solved: framed joints need no
    parent, so they come first (step 0) and a swing joint comes one step after its parent. The
    spine3 frame starts the arms and neck at step 0 beside the pelvis, so the tree takes four
    steps instead of its eight levels."""
    step = np.zeros(NUM_JOINTS, dtype=np.int64)
    for j in range(1, NUM_JOINTS):  # parents come before their children
        step[j] = 0 if j in _FRAMED else step[PARENTS[j]] + 1
    return step


def _plan() -> tuple[_LevelPlan, ...]:
    plan = []
    steps = _steps()
    for k in range(steps.max() + 1):
        level = np.flatnonzero(steps == k)
        js = np.array([j for j in level if len(CHILDREN[j]) == 1 and j not in _FRAMED], dtype=np.int64)
        ks = np.array([_LIMB_OF.get(int(j), -1) for j in js], dtype=np.int64)
        sel = np.flatnonzero(ks >= 0)
        cs = np.array([CHILDREN[j][0] for j in js], dtype=np.int64)
        limb = _LIMB_IDX[ks[sel]]
        plan.append(_LevelPlan(tuple(int(j) for j in _FRAMED if j in level), js, PARENTS[js].astype(np.int64), cs,
                               sel, ks[sel], (limb[:, 0], limb[:, 1], limb[:, 2])))
    return tuple(plan)


_FRAMED_JOINTS = np.array(list(_FRAMED), dtype=np.int64)
_FRAMED_IDX = np.array(list(_FRAMED.values()), dtype=np.int64)  # (F, 4): a_from, a_to, b_from, b_to
_PLAN = _plan()
_LEAVES = np.array([j for j in range(NUM_JOINTS) if not CHILDREN[j]], dtype=np.int64)


def solve_globals(
    joints: np.ndarray, info: RestInfo, twist: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global and local rotation matrices of posed joints (the core of local_rotations_from_joints).

    joints (N, 22, 3) float64; twist (4,) the limb twists of the frame before (online state).
    Returns (global (N, 22, 3, 3), local (N, 22, 3, 3), twist (4,) of the last frame).
    """
    n = joints.shape[0]
    glob = np.empty((n, NUM_JOINTS, 3, 3))
    prev = np.zeros(len(LIMBS)) if twist is None else np.array(twist, dtype=np.float64)
    for step in _PLAN:
        if step.framed:  # step 0 holds all of them
            a0, a1, b0, b1 = _FRAMED_IDX.T
            f = frame_matrix(joints[:, a1] - joints[:, a0], joints[:, b1] - joints[:, b0])
            glob[:, _FRAMED_JOINTS] = f @ info.framed_rest_t
        js, ps, cs, sel, ks = step.js, step.ps, step.cs, step.sel, step.ks
        if not len(js):
            continue
        gp = glob[:, ps]
        d_loc = np.einsum("nkji,nkj->nki", gp, joints[:, cs] - joints[:, js])
        g = gp @ rotation_between_units(info.swing_units[js], d_loc)
        if len(sel):
            angle, weight = _limb_twist(joints, g[:, sel], info, ks, step.limb_joints)
            # Sequential filter: the plane's twist where the limb is bent, the previous frame's
            # where it is straight (so batch and frame-by-frame agree).
            out = np.empty_like(angle)
            p = prev[ks]
            for t in range(n):
                p = _wrap(p + weight[t] * _wrap(angle[t] - p))
                out[t] = p
            prev[ks] = p
            g[:, sel] = g[:, sel] @ axis_angle_matrix(info.limb_dirs[ks], out)
        glob[:, js] = g
    glob[:, _LEAVES] = glob[:, PARENTS[_LEAVES]]
    loc = np.empty_like(glob)
    loc[:, 0] = glob[:, 0]
    loc[:, 1:] = np.swapaxes(glob[:, PARENTS[1:]], -1, -2) @ glob[:, 1:]
    return glob, loc, prev


def fk_matrices(loc: np.ndarray, root: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics on rotation matrices, level by level (same result as live.kinematics).

    loc (N, 22, 3, 3) local rotations; root (N, 3); offsets (22, 3) rest offsets from the parent.
    Returns (global (N, 22, 3, 3), joints (N, 22, 3)).
    """
    n = loc.shape[0]
    glob = np.empty_like(loc)
    pos = np.empty((n, NUM_JOINTS, 3))
    glob[:, 0] = loc[:, 0]
    pos[:, 0] = root
    for level in LEVELS[1:]:
        p = PARENTS[level]
        glob[:, level] = glob[:, p] @ loc[:, level]
        pos[:, level] = pos[:, p] + np.einsum("nkij,kj->nki", glob[:, p], offsets[level])
    return glob, pos


def _ancestry() -> np.ndarray:
    """(22, 22): A[j, i] = 1 where the bone into joint i lies on the chain from the root to j."""
    a = np.zeros((NUM_JOINTS, NUM_JOINTS))
    for j in range(1, NUM_JOINTS):
        i = j
        while i > 0:
            a[j, i] = 1.0
            i = int(PARENTS[i])
    return a


_ANCESTRY_BONES = _ancestry()[:, 1:]  # (22, 21): the root has no bone of its own


def joints_from_globals(glob: np.ndarray, root: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Joint positions (N, 22, 3) of a pose given as global rotations (N, 22, 3, 3): each bone's
    rest offset turned by its parent's global rotation, summed down the tree from the root (N, 3).
    The same joints as ``fk_matrices`` of the matching local rotations, in one einsum and one
    matmul with the constant ancestry matrix instead of a level-by-level loop."""
    bones = np.einsum("nkij,kj->nki", glob[:, PARENTS[1:]], offsets[1:])  # (N, 21, 3)
    return np.asarray(root, np.float64)[:, None, :] + _ANCESTRY_BONES @ bones


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


def estimate_rest_joints(joints: np.ndarray, template: np.ndarray | None = None) -> np.ndarray:
    """A T-pose rest skeleton (22 x 3) for a performer seen only as posed joints (T x 22 x 3).

    Bone lengths are the per-bone medians over frames; bone directions come from ``template``
    (default: the body library's mean T-pose, live.body.mean_rest_template, or the straight-leg
    live.skeleton.default_rest_joints() without a library; the straight legs make real performers
    6-10 % tall). The feet are put on the floor at the template's foot height, scaled by the leg
    length found.
    """
    from live.body import mean_rest_template
    from live.skeleton import default_rest_joints

    joints = np.asarray(joints, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
    if template is None:
        template = mean_rest_template()
    tpl = np.asarray(default_rest_joints() if template is None else template, dtype=np.float64)
    tpl_off = rest_offsets(tpl)
    rest = np.zeros((NUM_JOINTS, 3))
    for p, c in BONES:
        length = np.median(np.linalg.norm(joints[:, c] - joints[:, p], axis=-1))
        rest[c] = rest[p] + normalize(tpl_off[c]) * length
    feet = [_J["left_ankle"], _J["right_ankle"], _J["left_foot"], _J["right_foot"]]
    drop = -rest[feet, 1].min()
    # The template's lowest foot joint sits above the floor by a fraction of its leg length.
    tpl_clear = tpl[feet, 1].min() / tpl[0, 1]
    rest[:, 1] += drop / (1.0 - tpl_clear)
    return rest.astype(np.float32)

