"""Two-bone limb IK, and the numpy vector helpers the retargeter's per-body set-up runs on.

Matrices act on column vectors (v' = R v), like live/core/rotations.py. The IK of one frame's limbs
runs on plain floats (live/core/vec3.py: numpy's per-call overhead is most of the cost on a
limb's 3-vectors); ``two_bone_ik`` takes any leading batch shape and loops over it. The numpy
helpers (dot, normalize, cross) are pure and take any leading batch shape.
"""

from __future__ import annotations

import math

import numpy as np

from live.core import vec3 as v3

_EPS = 1e-12
# Levi-Civita symbol: one einsum against it replaces np.cross, which costs 5-10 times more on
# the few-element arrays of a body's joints.
_LC = np.zeros((3, 3, 3))
_LC[0, 1, 2] = _LC[1, 2, 0] = _LC[2, 0, 1] = 1.0
_LC[0, 2, 1] = _LC[2, 1, 0] = _LC[1, 0, 2] = -1.0


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (..., 3) arrays -> (...)."""
    return np.einsum("...i,...i->...", a, b)


def normalize(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> unit vectors (zero vectors stay zero)."""
    return v / np.maximum(np.sqrt(dot(v, v)), _EPS)[..., None]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (broadcasting)."""
    return np.einsum("ijk,...j,...k->...i", _LC, a, b)


def two_bone_ik(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    target: np.ndarray,
    bend_hint: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """World-space corrections that bring the end c of the chain a-b-c to ``target``.

    a, b, c: (..., 3) root, middle and end joint positions (hip, knee, ankle); target (..., 3);
    bend_hint (..., 3): the rotation axis along which the middle joint flexes, used when the limb
    is straight and its own plane is undefined (for a knee, the thigh's world x axis).
    Returns (delta_upper, delta_lower), each (..., 3, 3): the new global rotation of the upper
    bone is ``delta_upper @ G_a`` and of the lower bone ``delta_lower @ G_b``. Bone lengths are
    kept; an unreachable target leaves the limb pointing at it, fully stretched (minus 1e-4 of
    its length, so that the knee keeps a defined plane) or fully folded.
    """
    arrays = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (a, b, c, target, bend_hint)))
    lead = arrays[0].shape[:-1]
    rows = [x.reshape(-1, 3).tolist() for x in arrays]
    solved = [limb_ik(*limb) for limb in zip(*rows)]
    upper = np.array([u for u, _ in solved]).reshape(lead + (3, 3))
    lower = np.array([w for _, w in solved]).reshape(lead + (3, 3))
    return upper, lower


def soft_reach(distance: float, reach: float, soft: float) -> float:
    """Soft IK (Nicholas): the distance a limb of length ``reach`` is asked to span, eased so it
    straightens only asymptotically. Up to (1 - soft) x reach it is ``distance``; beyond, it
    approaches the reach exponentially, with a continuous slope. Near full extension the middle
    joint's position changes without bound per unit of distance (a knee snaps straight and snaps
    back), so a target moving past the reach would make the limb pop; eased, the end lags the
    target by at most soft / e x reach at the reach itself instead."""
    exact_up_to = reach * (1.0 - soft)
    if soft <= 0.0 or distance <= exact_up_to:
        return distance
    return exact_up_to + soft * reach * (1.0 - math.exp(-(distance - exact_up_to) / (soft * reach)))


def limb_ik(a: v3.Vec, b: v3.Vec, c: v3.Vec, target: v3.Vec, bend_hint: v3.Vec, soft: float = 0.0
            ) -> tuple[v3.Mat, v3.Mat]:
    """``two_bone_ik`` of one limb on plain floats (the per-frame path: a dozen times cheaper
    than numpy on one limb's 3-vectors); returns (delta_upper, delta_lower) as rows of floats.
    soft: ease the last ``soft`` of the reach (``soft_reach``; 0 = exact IK)."""
    ab, cb, ac, at = v3.sub(b, a), v3.sub(c, b), v3.sub(c, a), v3.sub(target, a)
    l_ab, l_cb, l_ac = v3.norm(ab), v3.norm(cb), v3.norm(ac)
    reach = l_ab + l_cb
    if soft > 0.0:
        l_want = v3.norm(at)
        eased = soft_reach(l_want, reach, soft)
        if eased < l_want:
            at = v3.scale(at, eased / l_want)
    l_at = min(max(v3.norm(at), abs(l_ab - l_cb) + 1e-4 * reach), reach * (1.0 - 1e-4))
    # Interior angles at the root and at the middle joint, wanted (law of cosines) minus now;
    # the bend plane's normal rotates both.
    turn_root = (math.acos(v3.clamp((l_cb**2 - l_ab**2 - l_at**2) / (-2.0 * l_ab * l_at)))
                 - math.acos(v3.clamp(v3.dot(ac, ab) / max(l_ac * l_ab, v3.EPS))))
    turn_mid = (math.acos(v3.clamp((l_at**2 - l_ab**2 - l_cb**2) / (-2.0 * l_ab * l_cb)))
                - math.acos(v3.clamp(-v3.dot(ab, cb) / max(l_ab * l_cb, v3.EPS))))
    plane = v3.cross(ac, ab)
    plane_n = v3.norm(plane)
    if plane_n < 1e-6 * max(l_ab * (l_ab + l_cb), v3.EPS):
        # A straight limb has no plane: bend about the hinge hint (its sign chosen to match
        # cross(ac, ab) of a naturally flexed limb).
        hint = v3.sub(bend_hint, v3.scale(ab, v3.dot(bend_hint, ab) / max(l_ab**2, v3.EPS)))
        axis = v3.scale(v3.unit(hint), -1.0)
    else:
        axis = v3.scale(plane, 1.0 / max(plane_n, v3.EPS))
    r0, r1 = v3.axis_angle(axis, turn_root), v3.axis_angle(axis, turn_mid)
    # The two bends keep the end on the old a-c line (up to rounding); swing it onto the target.
    end = v3.mv(r0, v3.add(ab, v3.mv(r1, cb)))
    upper = v3.mm(v3.between_units(v3.unit(end), at), r0)
    return upper, v3.mm(upper, r1)


def apply_limb_ik(
    glob: np.ndarray,
    loc: np.ndarray,
    pos: np.ndarray,
    offsets: np.ndarray,
    limbs: np.ndarray,
    hinges: np.ndarray,
    targets: np.ndarray,
    children: tuple[tuple[int, ...], ...],
    parents: np.ndarray,
    soft: float = 0.0,
) -> None:
    """Pose limbs of one frame so their end joints reach targets, in place.

    glob, loc (22, 3, 3) global and local rotations; pos (22, 3) joints; offsets (22, 3) rest
    offsets; limbs (K, 3) joint indices (root, middle, end); hinges (K, 3) rest hinge axes of the
    middle joints; targets (K, 3). The end joints keep their world orientation (a locked foot
    keeps its angle to the floor) and their descendants move rigidly with them. soft: soft IK
    (``soft_reach``), 0 = reach the targets exactly.
    """
    for (r, m, e), hinge, target in zip(np.asarray(limbs).tolist(), np.asarray(hinges).tolist(),
                                        np.asarray(targets, np.float64).tolist()):
        g_r0, g_m0, g_e = glob[r].tolist(), glob[m].tolist(), glob[e].tolist()
        a, b, c = pos[r].tolist(), pos[m].tolist(), pos[e].tolist()
        upper, lower = limb_ik(a, b, c, target, v3.mv(g_r0, hinge), soft)
        g_r, g_m = v3.mm(upper, g_r0), v3.mm(lower, g_m0)
        knee = v3.add(a, v3.mv(g_r, offsets[m].tolist()))
        end = v3.add(knee, v3.mv(g_m, offsets[e].tolist()))
        glob[r], glob[m] = g_r, g_m
        pos[m], pos[e] = knee, end
        loc[r] = v3.mtm(glob[parents[r]].tolist(), g_r)
        loc[m] = v3.mtm(g_r, g_m)
        loc[e] = v3.mtm(g_m, g_e)
        shift = v3.sub(end, c)
        stack = list(children[e])
        while stack:
            j = stack.pop()
            pos[j] += shift
            stack.extend(children[j])
