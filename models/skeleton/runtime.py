"""The live skeleton stage: depth frame -> person sample -> ONNX model -> filtered world joints.

numpy + onnxruntime only (the networks are trained by models/train/train_skeleton.py). Per frame:
``PersonFinder`` (models.skeleton.preprocess) -> the regressor on the person-frame sample ->
``PersonCloud.to_world`` -> flip guard -> temporal model (models.skeleton.temporal: the last half
second of estimates in, the current joints out) -> bone-length consistency -> One Euro filter, and a
per-joint confidence: the depth support near the joint (joint_confidence), zero for joints
outside the camera image. Nobody in view -> no skeleton (``process`` returns False), and the
temporal state is reset once the person has been gone for ``reset_after_s``.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import ModelError, UserInputError
from live.core.frames import DepthFrame, FrameResult, SkeletonFrame
from live.core.gravity import GravityEstimator, camera_imu_sample
from live.core.rotations import angle_deg
from models.skeleton.body_fit import body_fit
from models.skeleton.filters import BoneLengthKeeper, FlipGuard, OneEuroFilter, joint_confidence
from models.skeleton.preprocess import PersonCloud, PersonFinder
from models.skeleton.preprocess_config import PreprocessConfig
from models.skeleton.temporal import TemporalRefiner, temporal_model_path

log = logging.getLogger(__name__)

WEIGHTS_DIR = assets.weights_dir()
DEFAULT_MODEL = WEIGHTS_DIR / "skeleton.onnx"
BASELINE_MODEL = WEIGHTS_DIR / "skeleton_baseline.onnx"


class SkeletonRegressor:
    """An exported skeleton network in an onnxruntime session.

    ``regressor(points)``: person-frame points (N, 3) or (B, N, 3) float32 -> joints (22, 3) or
    (B, 22, 3) float32 in the same frame. ``num_points`` is what the model was trained on (from
    its model card next to the .onnx file; 256 when there is no card)."""

    def __init__(self, model_path: str | Path | None = None, threads: int = 1):
        from live.core.onnx import open_session

        self.path = Path(model_path) if model_path is not None else DEFAULT_MODEL
        self.session, self.card = open_session(self.path, threads=threads, what="skeleton model",
                                               retrain="livecap train skeleton")
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or inputs[0].shape[-1] != 3:
            raise ModelError(f"{self.path.name}: expected one (B, N, 3) input, got {[i.shape for i in inputs]}")
        self._input = inputs[0].name
        self.num_points = int(self.card.get("num_points", 256))
        share = self.card.get("preprocess", {}).get("edge_jump_share")
        self.edge_jump_share = None if share is None else float(share)

    def preprocess_config(self) -> PreprocessConfig:
        """The finder's settings this model was trained with (sample size, edge pixels)."""
        return PreprocessConfig(num_points=self.num_points, edge_jump_share=self.edge_jump_share)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        x = np.asarray(points, np.float32)
        single = x.ndim == 2
        if single:
            x = x[None]
        out = self.session.run(None, {self._input: np.ascontiguousarray(x)})[0]
        return out[0] if single else out


@dataclass
class StageCounters:
    frames: int = 0
    skeletons: int = 0
    nobody: int = 0
    resets: int = 0
    # Frames whose skeleton a lagging temporal model will give later (the first of a take).
    delayed: int = 0
    # Skeletons a lagging temporal model gave at the end of the stream (flush).
    flushed: int = 0
    # Samples of the camera's own IMU seen; ups adopted from it (the first, then each camera move).
    camera_imu_samples: int = 0
    gravity_updates: int = 0


def joints_in_view(joints_world: np.ndarray, frame: DepthFrame, width: int, height: int,
                   camera_to_world: np.ndarray | None = None) -> np.ndarray:
    """(22,) bool: each world joint (22, 3) is in front of the camera and inside its image
    (``camera_to_world``: the one the joints were solved in; default the frame's own)."""
    c2w = np.asarray(frame.camera_to_world if camera_to_world is None else camera_to_world, np.float64)
    cam = (np.asarray(joints_world, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    k = frame.intrinsics
    z = np.maximum(cam[:, 2], 1e-6)
    u = cam[:, 0] / z * k[0, 0] + k[0, 2]
    v = cam[:, 1] / z * k[1, 1] + k[1, 2]
    return (cam[:, 2] > 0.05) & (u >= 0) & (u < width) & (v >= 0) & (v < height)


class SkeletonStage:
    """Pipeline stage ``skeleton``: sets ``result.skeleton`` from ``result.depth``.

    temporal: the temporal model (True: the shipped one when it was trained behind this
    regressor, else skipped with a warning; a path: that model, which must match; False: off).
    lag: with temporal=True, the shipped model of that lag (frames at 30 fps, 0 = online): each
    skeleton comes out lag / 30 s later and much smoother (docs/skeleton.md); its t_ns is that of
    the frame it estimates.
    min_cutoff / beta: One Euro filter (Hz, and Hz per m/s); filter: One Euro on or off (None:
    on only without a temporal model); temporal=False, filter=False gives raw joints.
    keep_bones: bone lengths fixed per performer once learned (off by
    default: with the current model it costs ~10 mm MPJPE); flip_guard: undo whole-body
    left/right label flips. reset_after_s: forget the performer after this long without one.
    camera_height_m: the camera's height above the floor, for depth without a camera pose when
    the floor is not in view, used once the camera's IMU gives up (else the floor is guessed
    under the performer: a standing person's, wrong for one seated at a desk; docs/skeleton.md).
    body_check: until the performer has been seen moving, weigh a pick that fits its regressed
    skeleton badly against the rest of the image (``PersonFinder.find``'s judge; docs/skeleton.md,
    "Body check"). check_extrinsics: check a given camera pose against the floor or the walls in
    view and solve in the room's up where it is off (``GroundEstimator.check_given``; the
    skeleton is reported in the given world either way); False takes it as given."""

    name = "skeleton"

    def __init__(self, model_path: str | Path | None = None, threads: int = 1, *,
                 finder: PersonFinder | None = None, temporal: bool | str | Path = True, lag: int = 0,
                 min_cutoff: float = 1.5, beta: float = 3.0,
                 filter: bool | None = None, keep_bones: bool = False, flip_guard: bool = True,
                 reset_after_s: float = 0.5, camera_height_m: float | None = None, body_check: bool = True,
                 check_extrinsics: bool = True):
        self.regressor = SkeletonRegressor(model_path, threads)
        self.temporal = _open_temporal(temporal, self.regressor.path, threads, int(lag))
        self.lag_s = 0.0 if self.temporal is None else self.temporal.lag_s  # latency the model adds
        self.finder = finder or PersonFinder(self.regressor.preprocess_config())
        if camera_height_m is not None:
            self.finder.ground.camera_height_m = float(camera_height_m)
        self.finder.ground.check_given_pose = bool(check_extrinsics)
        self.min_cutoff, self.beta = float(min_cutoff), float(beta)
        # The temporal model smooths already (and better, docs/skeleton.md): One Euro on top would
        # only add lag, so by default it runs only without one.
        self.use_filter = self.temporal is None if filter is None else bool(filter)
        self.keep_bones, self.use_flip_guard = keep_bones, flip_guard
        self.body_check = bool(body_check)
        self.reset_after_ns = int(reset_after_s * 1e9)
        self._counters = StageCounters()
        self.last_cloud: PersonCloud | None = None
        self._last_t: int | None = None
        self._last_frame: DepthFrame | None = None  # for the in-view check of flushed skeletons
        # (t_ns, camera_to_world) of the last frames solved: a lagging model's skeleton is an
        # earlier frame's, drawn in that frame's camera.
        self._solved_in: deque[tuple[int, np.ndarray | None]] = deque(maxlen=16)
        # World up from the camera's own IMU while it stands still (live.core.gravity).
        self.gravity = GravityEstimator()
        self.reset()

    def reset(self) -> None:
        """Forget the performer (filters, bone lengths, flip history)."""
        self.euro = OneEuroFilter(min_cutoff=self.min_cutoff, beta=self.beta)
        self.bones = BoneLengthKeeper()
        self.flips = FlipGuard()
        if self.temporal is not None:
            self.temporal.reset()

    @property
    def counters(self) -> dict[str, int]:
        out = asdict(self._counters)
        out["flips"] = self.flips.flips
        out["flip_recoveries"] = self.flips.recoveries
        out["temporal_restarts"] = 0 if self.temporal is None else self.temporal.restarts
        out["temporal_jumps"] = 0 if self.temporal is None else self.temporal.jumps
        out["temporal_stills"] = 0 if self.temporal is None else self.temporal.stills
        out.update({f"finder_{k}": v for k, v in asdict(self.finder.counters).items()})
        return out

    @property
    def details(self) -> dict:
        """For stats.json: where up and the floor came from (given extrinsics, the camera's IMU,
        a floor plane, a level camera refined by the performer), each change of that source with
        its time, the camera's height above the floor of the last frame solved, the height
        the user gave (``--camera-height``, or None), and how far a given camera pose was turned
        to the room's up at the end (degrees; 0 when it agreed, None when none was given)."""
        finder = self.finder
        c2w = self._solved_in[-1][1] if self._solved_in else None
        fix = finder.ground.given_fix
        given = (finder.up_source or "").startswith("given")
        return {"up_source": finder.up_source,
                "up_source_changes": [{"t_ns": t, "source": s} for t, s in finder.ground.changes],
                "camera_height_m": None if c2w is None else round(float(c2w[1, 3]), 3),
                "camera_height_given_m": finder.ground.camera_height_m,
                "given_pose_turned_deg": None if not given else 0.0 if fix is None
                else round(angle_deg(fix[:3, 1], np.array([0.0, 1.0, 0.0])), 2)}

    def observe(self, frame: object) -> None:
        """Side frames in stream order. The samples of the camera's own IMU (a ``<camera>_imu``
        stream, live.core.gravity.camera_imu_sample) feed the gravity estimator, whose up in camera
        axes the finder uses when the depth frames carry no camera_to_world; other side frames
        (ground truth, a suit) carry nothing for this stage."""
        sample = camera_imu_sample(frame)
        if sample is None:
            return
        self._counters.camera_imu_samples += 1
        self.gravity.add(*sample)
        up = self.gravity.up_in_camera()
        if up is not None:
            self.finder.gravity_up = up
            self._counters.gravity_updates = self.gravity.updates

    def estimate(self, frame: DepthFrame) -> SkeletonFrame | None:
        """One depth frame -> filtered world skeleton, or None when nobody is in view."""
        self._counters.frames += 1
        if self._last_t is not None and frame.t_ns - self._last_t > self.reset_after_ns:
            self.reset()
            self._counters.resets += 1
            self._last_t = None
        judged: list[tuple[PersonCloud, np.ndarray]] = []
        cloud = self.finder.find(frame, judge=(lambda c: self._body_fit(c, judged)) if self.body_check else None)
        self.last_cloud = cloud
        if cloud is None:
            self._counters.nobody += 1
            return None
        local = next((j for c, j in judged if c.points is cloud.points), None)  # the same sample
        if local is None:
            local = self.regressor(cloud.points)
        local = local.astype(np.float64)
        support = joint_confidence(local, cloud.points)
        rot, trans = cloud.to_world[:3, :3], cloud.to_world[:3, 3]
        joints = local @ rot.T + trans
        if self.use_flip_guard:
            joints = self.flips(joints)
        self._last_t = frame.t_ns
        t_ns = frame.t_ns
        self._last_frame = frame
        self._solved_in.append((frame.t_ns, cloud.camera_to_world))
        if self.temporal is not None:
            refined = self.temporal(frame.t_ns, joints, support, cloud.to_world)
            if refined is None:  # a lagging model: this frame's skeleton comes later
                self._counters.delayed += 1
                return None
            t_ns, joints, support = refined.t_ns, refined.joints, refined.confidence
        return self._finish(t_ns, joints, support, frame)

    def _body_fit(self, cloud: PersonCloud, judged: list) -> float:
        """The finder's body check: how far the cloud lies from the bones of its regressed
        skeleton (the skeleton kept in ``judged``, so the cloud taken is not regressed twice)."""
        joints = self.regressor(cloud.points)
        judged.append((cloud, joints))
        return body_fit(joints, cloud.points)

    def _camera_to_world_of(self, t_ns: int) -> np.ndarray | None:
        """The camera_to_world the frame of time ``t_ns`` was solved in (a lagging model's
        skeleton belongs to an earlier frame)."""
        for t, c2w in reversed(self._solved_in):
            if t == t_ns:
                return c2w
        return self._solved_in[-1][1] if self._solved_in else None

    def _finish(self, t_ns: int, joints: np.ndarray, support: np.ndarray, frame: DepthFrame) -> SkeletonFrame:
        """Confidence (depth support, in view of ``frame``), bone lengths, One Euro: the frame out."""
        conf = support
        c2w = self._camera_to_world_of(t_ns)
        if frame.depth_mm is not None and frame.intrinsics is not None:
            h, w = frame.depth_mm.shape
            conf = conf * joints_in_view(joints, frame, w, h, c2w)
        if self.keep_bones:
            joints = self.bones(joints, conf)
        if self.use_filter:
            joints = self.euro(joints, t_ns * 1e-9)
        self._counters.skeletons += 1
        return SkeletonFrame(t_ns=t_ns, joints=joints.astype(np.float32),
                             confidence=np.clip(conf, 0.0, 1.0).astype(np.float32),
                             camera_to_world=None if c2w is None else np.asarray(c2w, np.float64))

    def flush(self) -> list[SkeletonFrame]:
        """At the end of a stream: the skeletons a lagging temporal model still owes (the last
        ``lag`` frames, oldest first; none online), so that a replay gets one per frame found."""
        if self.temporal is None or self._last_frame is None:
            return []
        out = [self._finish(r.t_ns, r.joints, r.confidence, self._last_frame) for r in self.temporal.flush()]
        self._counters.flushed += len(out)
        return out

    def process(self, result: FrameResult) -> bool:
        if result.depth is None:
            return False
        skeleton = self.estimate(result.depth)
        if skeleton is None:
            return False
        result.skeleton = skeleton
        return True

    def drain(self) -> list[FrameResult]:
        """The pipeline's end-of-stream call: ``flush`` as results of their own frames' times."""
        return [FrameResult(t_ns=sk.t_ns, skeleton=sk) for sk in self.flush()]


def _open_temporal(temporal: bool | str | Path, regressor_path: Path, threads: int,
                   lag: int = 0) -> TemporalRefiner | None:
    """The stage's temporal model, or None (off, or the optional default is absent or was
    trained behind another regressor: it would correct errors this regressor does not make).
    A lag asks for a model that must exist and match."""
    if lag < 0:
        raise UserInputError(f"the skeleton lag is a number of frames >= 0, not {lag}")
    if temporal is False or temporal is None:
        if lag:
            raise UserInputError("a skeleton lag needs the temporal model (it is the one that lags)")
        return None
    path = temporal_model_path(lag, regressor_path) if temporal is True else Path(temporal)
    if temporal is True and not path.is_file():
        if lag:
            shipped = sorted(p.stem for p in path.parent.glob("skeleton_temporal_lag*.onnx"))
            raise UserInputError(f"no temporal skeleton model with lag {lag} ({path.name}); shipped: "
                                 f"lag 0{''.join(', ' + s.rsplit('lag', 1)[1] for s in shipped)}")
        return None
    refiner = TemporalRefiner(path, threads)
    if temporal is not True and lag and refiner.lag != lag:
        raise UserInputError(f"{path.name} has lag {refiner.lag}, not the {lag} asked for")
    if refiner.matches(regressor_path):
        return refiner
    msg = f"{path.name} was trained behind another skeleton model than {regressor_path.name}"
    if temporal is not True or lag:
        raise ModelError(f"{msg} (retrain it: python -m models.train.train_skeleton_temporal --regressor ...)")
    log.warning("%s: temporal refinement off", msg)
    return None


__all__ = ["SkeletonRegressor", "SkeletonStage", "StageCounters", "joints_in_view", "DEFAULT_MODEL",
           "BASELINE_MODEL"]
