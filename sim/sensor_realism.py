"""Training scenes that look like the depth users have, not only like our own virtual camera.

What differs between our renders and real sensors (docs/depth_realism.md measures it on the
shared real frames) is drawn at random per training job: the sensor (stereo or time of flight,
320x240 to 640x480), its noise (flying pixels at depth edges, holes in blobs, silhouettes kept
whole as filled datasets have them), clothes and hair on the body (``sim.clothing``), a desk edge
or a chair back between camera and performer, another person behind, the camera anywhere from
0.5 to 2.5 m high and pitched from 20 degrees up to 45 down, rooms whose floor returns no depth,
frames without extrinsics (the runtime's finder then estimates up and the floor itself), and a
quarter of the performers seated on a chair, crouching or moving in place (``sim.postures``).

``HARD_VIEWS`` draws the views the regressor gets most wrong more often (seated and crouching
performers, close-ups, a desk or chair back in front, steep pitch) for training data weighted
toward them; the held-out "val_real" set keeps ``USUAL_VIEWS``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from live.core.skeleton import JOINT_INDEX
from sim.clothing import Outfit, dress, random_outfit
from sim.room import Box, Room, capsule_body, merge_meshes

#: Bump when what a realism job draws changes (it keys the training-data cache).
REALISM_VERSION = 2
#: Share of realism jobs per posture (sim.postures); the rest perform the clip as recorded.
POSTURE_ODDS = {"seated": 0.12, "crouching": 0.08, "in-place": 0.05}
PITCH_RANGE_DEG = (-20.0, 45.0)  # looking up 20 degrees .. down 45
HIDE_EXTRINSICS_SHARE = 0.4
NO_FLOOR_SHARE = 0.15


@dataclass(frozen=True)
class ViewOdds:
    """How often a realism job draws each kind of view (the draws themselves are the same)."""

    posture: dict[str, float] = field(default_factory=lambda: dict(POSTURE_ODDS))
    closeup: float = 0.15  # share of close-ups (0.5-1.3 m, aimed at the chest)
    desk: float = 0.12  # a desk top in front (close-ups: desk_closeup)
    desk_closeup: float = 0.5
    chair_back: float = 0.12  # a chair or sofa back in front, or beside
    pitch_spread_deg: float = 17.0  # the camera pitched off the performer by up to this


USUAL_VIEWS = ViewOdds()
#: Training views weighted toward those the regressor gets most wrong (docs/results.md, val_real
#: per view condition): 45 % seated or crouching, twice the close-ups and occluders, steeper pitch.
HARD_VIEWS = ViewOdds(posture={"seated": 0.27, "crouching": 0.18, "in-place": 0.05}, closeup=0.3,
                      desk=0.3, desk_closeup=0.6, chair_back=0.3, pitch_spread_deg=30.0)


def random_posture(rng: np.random.Generator, odds: ViewOdds = USUAL_VIEWS) -> str:
    """A job's posture: mostly the clip as recorded, sometimes seated, crouching or in place."""
    x, acc = rng.random(), 0.0
    for name, p in odds.posture.items():
        acc += p
        if x < acc:
            return name
    return "clip"


def realism_motion(motion, seed: int, odds: ViewOdds = USUAL_VIEWS):
    """(the job's motion in its posture, the posture): drawn from the job's seed alone, so the
    scene's other draws do not depend on it."""
    from sim.postures import apply_posture

    posture = random_posture(np.random.default_rng([seed, 17]), odds)
    return apply_posture(motion, posture), posture


def random_noise(rng: np.random.Generator):
    """A sensor noise model drawn around each sensor's typical values (sim.depth_camera)."""
    from sim.depth_camera import NoiseModel

    width = int(rng.choice(3, p=[0.25, 0.55, 0.2]))  # 0: silhouettes filled (post-processed depth)
    return NoiseModel(
        disparity_sigma_px=None if rng.random() < 0.6 else float(rng.uniform(0.05, 0.3)),
        edge_jump_px=1.0 if width else 0.0, edge_width_px=max(width, 1),
        occlusion=bool(rng.random() < 0.8), grazing_deg=float(rng.uniform(70.0, 88.0)),
        dropout=float(rng.uniform(0.0, 0.01)), noise_block_px=int(rng.integers(1, 4)),
        flying_pixels=float(rng.uniform(0.05, 0.6)) if rng.random() < 0.6 else 0.0,
        hole_blobs=float(rng.uniform(0.0, 0.04)) if rng.random() < 0.5 else 0.0,
        hole_blob_px=int(rng.integers(6, 20)))


def realistic_view(camera: str, closeup: bool, seed: int, rng: np.random.Generator,
                   odds: ViewOdds = USUAL_VIEWS):
    """(VirtualDepthCamera, Room) around a performer at the origin: close-ups 0.5-1.3 m aimed at
    the chest, else 1.2-5 m, 0.5-2.5 m high, any yaw, pitched off the performer by up to
    ``odds.pitch_spread_deg`` within PITCH_RANGE_DEG; a random room cleared between camera and
    performer."""
    from sim.depth_camera import VirtualDepthCamera, look_at_camera
    from sim.room import clear_view, random_room

    if closeup:
        distance, height, target_y = rng.uniform(0.5, 1.3), rng.uniform(1.0, 1.7), rng.uniform(1.1, 1.4)
    else:
        distance, height, target_y = rng.uniform(1.2, 5.0), rng.uniform(0.5, 2.5), 1.0
    look = np.degrees(np.arctan2(height - target_y, distance)) + rng.uniform(-odds.pitch_spread_deg, odds.pitch_spread_deg)
    pitch = np.radians(np.clip(look, *PITCH_RANGE_DEG))
    c2w = look_at_camera(distance, height, rng.uniform(-np.pi, np.pi), float(pitch), (0.0, target_y, 0.0))
    cam = VirtualDepthCamera(camera, c2w, noise=random_noise(rng), seed=seed)
    room = random_room(rng, keep_out_m=1.0)
    room = replace(room, width=float(rng.uniform(3.5, room.width)), depth=float(rng.uniform(3.5, room.depth)),
                   floor=bool(rng.random() >= NO_FLOOR_SHARE))
    return cam, clear_view(room, c2w[:3, 3])


@dataclass(frozen=True)
class SceneExtras:
    """What a realism job adds around the performer: an outfit, boxes in front (a desk edge, a
    chair back), another person behind (their joints per frame, or None), hidden extrinsics."""

    outfit: Outfit | None
    boxes: tuple[Box, ...]
    bystander: np.ndarray | None  # (T, 22, 3) world joints, or None
    hide_extrinsics: bool
    outward: int  # +1: the body mesh's faces wind outward

    def room(self, room: Room) -> Room:
        return replace(room, boxes=room.boxes + self.boxes)

    def mesh(self, vertices: np.ndarray, body, joints: np.ndarray, frame: int | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """The posed body (dressed) and the bystander of ``frame`` as one mesh (V, 3), (F, 3)."""
        faces = np.asarray(body.faces)
        if self.outfit is not None:
            vertices = dress(vertices, faces, body.weights, joints, self.outfit, self.outward)
        if self.bystander is None:
            return np.asarray(vertices, np.float32), faces
        t = 0 if frame is None else frame % len(self.bystander)
        v2, f2 = capsule_body(self.bystander[t], n_lon=12, n_lat=8)
        v, f = merge_meshes([(np.asarray(vertices, np.float32), faces.astype(np.int32)), (v2, f2)])
        return v, f


def random_extras(rng: np.random.Generator, body, joints: np.ndarray, frames: np.ndarray,
                  camera_to_world: np.ndarray, closeup: bool, posture: str = "clip",
                  odds: ViewOdds = USUAL_VIEWS) -> SceneExtras:
    """Draw a job's SceneExtras. joints (T, 22, 3) world of the performer (near the origin);
    frames the job's frame indices; a seated performer gets a chair under them."""
    from sim.depth_camera import closed_mesh_winding

    eye = np.asarray(camera_to_world, np.float64)[[0, 2], 3]
    toward = eye / max(float(np.linalg.norm(eye)), 1e-9)  # horizontal unit vector, performer -> camera
    yaw = float(np.arctan2(toward[0], toward[1]))
    boxes: list[Box] = []
    if rng.random() < (odds.desk_closeup if closeup else odds.desk):  # a desk top between camera and performer
        depth, width = rng.uniform(0.5, 0.8), rng.uniform(1.0, 1.6)
        top, thick = rng.uniform(0.68, 0.8), rng.uniform(0.03, 0.06)
        c = toward * (rng.uniform(0.3, 0.5) + depth / 2)
        boxes.append(Box((float(c[0]), float(top - thick / 2), float(c[1])), (width, thick, depth), yaw))
    if rng.random() < odds.chair_back:  # a chair or sofa back in front, or beside
        side = rng.uniform(-0.5, 0.5)
        c = toward * rng.uniform(0.35, 0.7) + side * np.array([toward[1], -toward[0]])
        h = rng.uniform(0.8, 1.0)
        boxes.append(Box((float(c[0]), float(h / 2), float(c[1])), (rng.uniform(0.4, 0.6), h, 0.06), yaw))
    bystander = None
    if rng.random() < 0.15:  # another person behind the performer, walking their own clip
        lateral = rng.uniform(-1.0, 1.0) * np.array([toward[1], 0.0, -toward[0]])
        behind = -rng.uniform(1.2, 2.5) * np.array([toward[0], 0.0, toward[1]])
        offset = lateral + behind
        lag = int(rng.integers(len(joints)))
        order = (np.asarray(frames) + lag) % len(joints)
        other = np.zeros((int(np.max(frames)) + 1, *joints.shape[1:]), np.float64)
        other[frames] = joints[order] - joints[order, JOINT_INDEX["pelvis"]][:, None] * [1.0, 0.0, 1.0] + offset
        bystander = other
    if posture == "seated":
        from sim.postures import seat_boxes

        seat = seat_boxes(joints[np.asarray(frames)])
    outfit = random_outfit(rng) if rng.random() < 0.85 else None
    outward = closed_mesh_winding(np.asarray(body.vertices, np.float32), np.asarray(body.faces)) or 1
    hide = bool(rng.random() < HIDE_EXTRINSICS_SHARE)
    if posture == "seated":
        boxes += list(seat)
    return SceneExtras(outfit, tuple(boxes), bystander, hide, outward)


__all__ = ["REALISM_VERSION", "POSTURE_ODDS", "ViewOdds", "USUAL_VIEWS", "HARD_VIEWS", "SceneExtras", "random_posture", "realism_motion", "random_noise", "realistic_view", "random_extras"]
