"""The learned online retargeter: an ONNX GRU network run one frame at a time (onnxruntime).

The network (models/train/retarget_nets.py) reads per frame the source joints relative to the
pelvis, the bone directions, the root velocity and height (in source leg lengths) and both
T-poses, and outputs the target's global joint rotations (6D; local ones follow) and a root
correction; its two GRU states are explicit ONNX inputs
and outputs that this class carries from frame to frame. Same interface as AnalyticRetargeter,
so the pipeline can swap them (``--retarget analytic|learned``). See docs/learned_retargeting.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import ModelError, UserInputError
from live.core.frames import AvatarPose, GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics, joints_from_global_matrices, local_matrices
from live.core.rotations import matrix_to_quat, sixd_to_matrix
from live.core.skeleton import NUM_JOINTS, PARENTS, pelvis_height, rest_offsets
from live.core.timing import FrameClock, frame_interval_s
from live.retarget.feet import FootPlanter
from live.retarget.interface import step_frame

DEFAULT_MODEL = assets.weight("retarget.onnx")
TRAIN_FPS = 30.0


def rest_features(rest: np.ndarray) -> np.ndarray:
    """(22, 3) T-pose -> (66,) float32: joints relative to the pelvis / leg length."""
    rest = np.asarray(rest, np.float64)
    return ((rest - rest[0]) / max(pelvis_height(rest), 1e-3)).astype(np.float32).ravel()


def source_features(joints: np.ndarray, prev_root: np.ndarray | None, rest_feat: np.ndarray,
                    leg: float, velocity_scale: float = 1.0) -> np.ndarray:
    """One frame's encoder input (199,) float32, as retarget_nets.source_features.

    joints (22, 3) world source joints; prev_root (3,) or None on the first frame (zero velocity);
    velocity_scale turns a per-frame root step into a per-1/30 s one when the frame rate differs."""
    root = joints[0]
    pose = (joints - root) / leg
    bones = joints[1:] - joints[PARENTS[1:]]
    dirs = bones / np.maximum(np.linalg.norm(bones, axis=1, keepdims=True), 1e-6)
    vel = np.zeros(3) if prev_root is None else (root - prev_root) / leg * velocity_scale
    return np.concatenate([pose.ravel(), dirs.ravel(), vel, [root[1] / leg], rest_feat]).astype(np.float32)


def _rest_joints(name: str, rest: np.ndarray) -> np.ndarray:
    rest = np.asarray(rest, np.float64)
    if rest.shape != (NUM_JOINTS, 3):
        raise UserInputError(f"{name} must be (22, 3), got {rest.shape}")
    return rest


class LearnedRetargeter:
    """Stateful, frame-by-frame learned retargeter from a source body to a target body (a
    Retargeter, live/retarget/interface.py).

    model_path: the .onnx file (default models/weights/retarget.onnx); source_rest, target_rest:
    (22, 3) T-poses. fps: frame rate assumed when ``step`` is not given ``dt``. threads: onnxruntime
    intra-op threads (1: the network is small and the machine is shared). foot_lock / floor: the
    analytic retargeter's foot placement after the network (live/retarget/feet.py); off here, so
    that the class is the network alone, and on in the pipeline's retarget stage."""

    def __init__(self, model_path: str | Path | None, source_rest: np.ndarray, target_rest: np.ndarray,
                 *, fps: float = 30.0, threads: int = 1, foot_lock: bool = False, floor: bool = False):
        from live.core.onnx import open_session

        self.path = Path(model_path) if model_path is not None else DEFAULT_MODEL
        self.session, self.card = open_session(self.path, threads=threads, what="retargeting model",
                                               retrain="livecap train retarget")
        shapes = {i.name: i.shape for i in self.session.get_inputs()}
        if set(shapes) != {"source", "target", "h_enc", "h_dec"}:
            raise ModelError(f"{self.path.name}: expected inputs source, target, h_enc, h_dec; got {sorted(shapes)}")
        self._h_shapes = {k: tuple(int(d) for d in shapes[k]) for k in ("h_enc", "h_dec")}
        self.target_rest = _rest_joints("target_rest", target_rest)
        self.tgt_leg = max(pelvis_height(self.target_rest), 1e-3)
        self.set_source_rest(source_rest)
        self._tgt_feat = rest_features(self.target_rest)[None]
        self._offsets = rest_offsets(self.target_rest)
        self.dt = frame_interval_s(fps)
        self.clock = FrameClock()
        self.feet = FootPlanter(self.target_rest, self._offsets, foot_lock=foot_lock, floor=floor)
        self.reset()

    @property
    def contact(self) -> np.ndarray:
        """(2,) bool: left, right foot in contact on the last frame (with foot_lock)."""
        return self.feet.contact

    def set_source_rest(self, rest_joints: np.ndarray) -> None:
        """New performer proportions (rest joints (22, 3)); GRU states and contacts are kept."""
        self.source_rest = _rest_joints("source_rest", rest_joints)
        self.src_leg = max(pelvis_height(self.source_rest), 1e-3)
        self.ratio = self.tgt_leg / self.src_leg
        self._src_feat = rest_features(self.source_rest)

    def reset(self) -> None:
        """Forget the motion so far (GRU states, last root, foot contacts, last timestamp)."""
        self.h_enc = np.zeros(self._h_shapes["h_enc"], np.float32)
        self.h_dec = np.zeros(self._h_shapes["h_dec"], np.float32)
        self._prev_root: np.ndarray | None = None
        self.clock.reset()
        self.feet.reset()
        # Global rotations (22, 3, 3) of the last step's target pose (for skinning).
        self.last_globals: np.ndarray | None = None

    def step(self, pose: np.ndarray, root: np.ndarray | None = None,
             dt: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Retarget one frame.

        pose: source joints (22, 3) world metres, or local rotations (22, 4) with ``root`` (3,)
        (turned into joints by FK on the source T-pose). Returns (root (3,), rotations (22, 4),
        joints (22, 3)) of the target body."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape == (NUM_JOINTS, 4):
            if root is None:
                raise UserInputError("rotations need a root position")
            pose = forward_kinematics(pose, np.asarray(root, np.float64), self.source_rest)[0]
        elif pose.shape != (NUM_JOINTS, 3):
            raise UserInputError(f"a frame is (22, 3) joints or (22, 4) rotations, got {pose.shape}")
        scale = TRAIN_FPS * (self.dt if dt is None else dt)
        feat = source_features(pose, self._prev_root, self._src_feat, self.src_leg, 1.0 / max(scale, 1e-6))
        self._prev_root = pose[0].copy()
        d6, droot, self.h_enc, self.h_dec = self.session.run(
            None, {"source": feat[None], "target": self._tgt_feat, "h_enc": self.h_enc, "h_dec": self.h_dec})
        glob = sixd_to_matrix(d6[0].astype(np.float64))  # the network gives world rotations
        loc = local_matrices(glob)
        root_t = pose[0] * self.ratio + droot[0].astype(np.float64) * self.tgt_leg
        joints = joints_from_global_matrices(glob[None], root_t[None], self._offsets)[0]
        self.feet(glob, loc, joints, self.dt if dt is None else dt)
        self.last_globals = glob
        return root_t, matrix_to_quat(loc), joints

    def process(self, frame: SkeletonFrame | GroundTruth) -> AvatarPose:
        """Retarget a SkeletonFrame (joints) or GroundTruth (rotations + root); dt from t_ns."""
        return step_frame(self.step, frame, self.clock.tick(frame.t_ns))


def learned_retarget_motion(model_path: str | Path | None, source_rest: np.ndarray, target_rest: np.ndarray,
                            joints: np.ndarray, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offline batch: joints T x 22 x 3 through a fresh LearnedRetargeter, frame by frame.
    Returns (root T x 3, rotations T x 22 x 4, joints T x 22 x 3)."""
    rt = LearnedRetargeter(model_path, source_rest, target_rest, fps=fps)
    frames = [rt.step(j) for j in np.asarray(joints, np.float64)]
    if not frames:
        return np.zeros((0, 3)), np.zeros((0, NUM_JOINTS, 4)), np.zeros((0, NUM_JOINTS, 3))
    return tuple(np.stack(x) for x in zip(*frames))  # type: ignore[return-value]
