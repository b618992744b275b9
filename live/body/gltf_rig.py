"""An avatar file's own bones, as the outputs drive them: ``AvatarRig`` (built by
live/body/gltf_avatar.py for a VRM / glTF humanoid, ``Body.rig``).

Our poses are local rotations of the 22 canonical joints relative to the T-pose, on rest frames
aligned with the world (identity = T-pose). A file's bones have frames of their own: a VRM 0.x
is normalised (every bone's rest rotation is the identity), a VRM 1.0 or a Blender export need
not be (bone rolls, a turned root node), and a file may lack bones we have (no upperChest, no
neck, no shoulders, no toes) or have nodes between its humanoid bones. The rig holds what turns
a canonical pose into the local values of the file's own bones:

- ``fit_pose``: a canonical joint the file has no bone for (a point placed between two bones)
  turns with its parent (local rotation = identity); when it is its real parent's only child,
  that parent is first swung so the next joint stays where the retargeted pose put it. After
  this every canonical joint that is a file bone is where the file's own skeleton puts it.
- ``bone_values``: per bone sent (the canonical joints the file has a bone for, then its
  fingers, eyes and jaw at rest), the local position and local rotation to give that bone, in
  its own transform parent's frame (nodes between bones stay at rest). A bone's posed world
  rotation is its rest world rotation W0 turned by the global rotation G of the canonical joint
  it follows, so its local rotation is
      L = W0_parent^-1 . G_parent_joint^-1 . G_joint . W0_bone
  (G_parent_joint = identity for a parent above the hips, which never moves). The hips' local
  position puts them at the pelvis world position through the rest transform of their parent.

Frames: everything here is in our frame (y up, facing +z, left at +x; the file turned by the
avatar's ``to_ours`` rotation T, its node frames conjugated, W -> T W T). Mirrored into Unity's
frame (live/outputs/unity.py) these are the values of the file's nodes as UniVRM imports them:
VRM 0.x with z reversed, VRM 1.0 with x reversed (both are T then the x mirror).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.rotations import matrix_to_quat, quat_conjugate, quat_identity, quat_multiply, quat_normalize
from live.core.skeleton import CHILDREN, NUM_JOINTS, PARENTS, rest_offsets


@dataclass(frozen=True, eq=False)
class AvatarRig:
    """The file's bones as outputs drive them (module docstring). B bones, parents first.

    names (B,): Unity HumanBodyBones name of each bone (VRM's humanoid names capitalised);
    joint (B,): the canonical joint whose global rotation turns the bone; parent_joint (B,): the
    same for the bone's transform parent node, -1 for a parent above the hips (at rest);
    rest, parent_rest (B, 4): rest world rotations (w, x, y, z) of the bone and of its transform
    parent; local_position (B, 3): the bone's rest translation in its parent's frame (metres,
    scaled as the file's parents scale); hips_parent (4, 4): rest world matrix of the hips'
    transform parent; virtual (22,): canonical joints the file has no bone for; kind: "vrm0",
    "vrm1" or "skin". All in our frame.
    """

    names: tuple[str, ...]
    joint: np.ndarray
    parent_joint: np.ndarray
    rest: np.ndarray
    parent_rest: np.ndarray
    local_position: np.ndarray
    hips_parent: np.ndarray
    virtual: np.ndarray
    kind: str

    def bone_values(self, root: np.ndarray, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(local positions (B, 3), local rotations (B, 4) (w, x, y, z)) of the bones for a canonical
        pose: root (3,) pelvis world position, rotations (22, 4) local (as fitted by ``fit_pose``)."""
        glob = _global_quats(np.asarray(rotations, np.float64))
        g_parent = np.where((self.parent_joint >= 0)[:, None], glob[np.maximum(self.parent_joint, 0)],
                            quat_identity((len(self.names),)))
        q = quat_multiply(quat_conjugate(self.parent_rest),
                          quat_multiply(quat_conjugate(g_parent), quat_multiply(glob[self.joint], self.rest)))
        pos = self.local_position.copy()
        pos[0] = (np.linalg.inv(self.hips_parent) @ np.append(np.asarray(root, np.float64), 1.0))[:3]
        return pos, quat_normalize(q)

    def fit_pose(self, glob: np.ndarray, joints: np.ndarray, rest_joints: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A retargeted pose (global rotation matrices (22, 3, 3), joints (22, 3)) made one the
        file's skeleton can take: (global matrices, local rotations (22, 4), joints (22, 3))."""
        return fit_pose(glob, joints, rest_joints, self.virtual)


def _global_quats(rotations: np.ndarray) -> np.ndarray:
    out = np.empty_like(rotations)
    for j, p in enumerate(PARENTS):
        out[j] = rotations[j] if p < 0 else quat_multiply(out[p], rotations[j])
    return quat_normalize(out)


def _rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation matrix taking direction u to direction v (identity for a zero vector)."""
    nu, nv = np.linalg.norm(u), np.linalg.norm(v)
    if nu < 1e-9 or nv < 1e-9:
        return np.eye(3)
    u, v = u / nu, v / nv
    c, d = np.cross(u, v), float(np.dot(u, v))
    if d < -1.0 + 1e-9:  # opposite: half a turn about an axis orthogonal to u
        axis = np.cross(u, (1.0, 0.0, 0.0) if abs(u[0]) < 0.9 else (0.0, 1.0, 0.0))
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + d)


def fit_pose(glob: np.ndarray, joints: np.ndarray, rest_joints: np.ndarray, virtual: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``AvatarRig.fit_pose`` as a pure function: each virtual joint (parents first) takes its
    parent's global rotation; when the parent is a file bone whose only child it is and it has one
    child itself, the parent is first swung (shortest arc) so that child keeps its posed direction
    from the parent. Children keep their global rotations. Returns (global (22, 3, 3), local
    quaternions (22, 4), joints (22, 3) by forward kinematics from the root joints[0])."""
    g = np.array(glob, np.float64, copy=True)
    x = np.asarray(joints, np.float64)
    rest = np.asarray(rest_joints, np.float64)
    for j in range(1, NUM_JOINTS):
        if not virtual[j]:
            continue
        p = int(PARENTS[j])
        if not virtual[p] and len(CHILDREN[p]) == 1 and len(CHILDREN[j]) == 1:
            c = CHILDREN[j][0]
            g[p] = _rotation_between(g[p] @ (rest[c] - rest[p]), x[c] - x[p]) @ g[p]
        g[j] = g[p]
    offsets = rest_offsets(rest)
    out = np.empty((NUM_JOINTS, 3))
    out[0] = x[0]
    for j in range(1, NUM_JOINTS):
        out[j] = out[PARENTS[j]] + g[PARENTS[j]] @ offsets[j]
    loc = g.copy()
    loc[1:] = np.swapaxes(g[PARENTS[1:]], -1, -2) @ g[1:]
    return g, matrix_to_quat(loc), out


def _rotation_of(m: np.ndarray) -> np.ndarray:
    """The rotation of a 3x3 linear map (its polar factor: scale and shear removed)."""
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:  # a mirroring node: keep a proper rotation
        u[:, -1] *= -1
        r = u @ vt
    return r


def build_rig(kind: str, world: np.ndarray, parents: np.ndarray, to_ours: np.ndarray,
              real: dict[int, tuple[int, str]], extras: dict[int, str]) -> AvatarRig:
    """The rig of a file: world (N, 4, 4) node rest matrices in the file's frame (the T-pose), parents
    (N,), to_ours (4, 4) file -> our frame (a rotation T about y and a lift), real: canonical joint ->
    (node, HumanBodyBones name) for the joints that are a file bone, extras: node -> HumanBodyBones
    name of the fingers, eyes and jaw."""
    t = to_ours[:3, :3]
    conj = np.eye(4)
    conj[:3, :3] = t

    def ours(m: np.ndarray) -> np.ndarray:  # a node's rest world matrix in our frame, frames conjugated
        return to_ours @ m @ conj.T

    owner = {node: j for j, (node, _) in real.items()}
    follow = np.full(len(parents), -1, np.int64)  # node -> the canonical joint it turns with, -1: none
    for n in range(len(parents)):
        k = n
        while k >= 0 and k not in owner:
            k = int(parents[k])
        follow[n] = owner[k] if k >= 0 else -1

    def depth(n: int) -> int:
        d = 0
        while parents[n] >= 0:
            n, d = int(parents[n]), d + 1
        return d

    nodes = [real[j][0] for j in sorted(real)]
    names = [real[j][1] for j in sorted(real)]
    for n in sorted(extras, key=lambda n: (depth(n), n)):
        if n not in owner and follow[n] >= 0:
            nodes.append(n)
            names.append(extras[n])
    world_ours = np.stack([ours(world[n]) for n in range(len(parents))])
    rest, parent_rest, local, pjoint = [], [], [], []
    for n in nodes:
        p = int(parents[n])
        pm = world_ours[p] if p >= 0 else ours(np.eye(4))
        rest.append(_rotation_of(world_ours[n, :3, :3]))
        parent_rest.append(_rotation_of(pm[:3, :3]))
        local.append((np.linalg.inv(pm) @ world_ours[n])[:3, 3])
        pjoint.append(int(follow[p]) if p >= 0 else -1)
    hips = real[0][0]
    hp = int(parents[hips])
    virtual = np.array([j not in real for j in range(NUM_JOINTS)])
    return AvatarRig(names=tuple(names), joint=np.array([follow[n] for n in nodes], np.int64),
                     parent_joint=np.array(pjoint, np.int64), rest=matrix_to_quat(np.stack(rest)),
                     parent_rest=matrix_to_quat(np.stack(parent_rest)), local_position=np.stack(local),
                     hips_parent=world_ours[hp] if hp >= 0 else ours(np.eye(4)), virtual=virtual, kind=kind)
