"""A sink that scores the performer's skeleton against ground truth when a session has it."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from live.core.depth import between_worlds
from live.core.frames import FrameResult
from live.core.metrics import mpjpe, pa_mpjpe, pck


class AccuracySink:
    """Scores each skeleton against the ground truth of its own t_ns: the frame's, or with a
    lagging temporal model that of an earlier frame (the last ``keep`` truths are kept).
    ``true_camera_to_world``: the camera's real extrinsics when the depth stream withholds them
    (``set_true_camera``); each truth is then moved into the frame its skeleton was solved in."""

    true_camera_to_world: np.ndarray | None = None

    def set_true_camera(self, camera_to_world: np.ndarray | None) -> None:
        self.true_camera_to_world = None if camera_to_world is None else np.asarray(camera_to_world, np.float64)

    def __init__(self, keep: int = 64) -> None:
        self.pred: list[np.ndarray] = []
        self.gt: list[np.ndarray] = []
        self.frames_with_truth = 0
        self._truth: OrderedDict[int, np.ndarray] = OrderedDict()
        self._keep = keep

    def send(self, result: FrameResult) -> None:
        if result.truth is not None and result.truth.t_ns == result.t_ns:
            self.frames_with_truth += 1
            self._truth[result.t_ns] = np.asarray(result.truth.joints, np.float64)
            while len(self._truth) > self._keep:
                self._truth.popitem(last=False)
        if result.skeleton is not None and result.skeleton.t_ns in self._truth:
            self.pred.append(np.asarray(result.skeleton.joints, np.float64))
            truth = self._truth[result.skeleton.t_ns]
            solved = result.skeleton.camera_to_world
            if self.true_camera_to_world is not None and solved is not None:
                truth = between_worlds(truth, self.true_camera_to_world, solved)
            self.gt.append(truth)

    def close(self) -> None:
        pass

    def summary(self) -> dict:
        if not self.pred:
            return {"frames_with_truth": self.frames_with_truth, "frames_scored": 0}
        p, g = np.stack(self.pred), np.stack(self.gt)
        return {"frames_with_truth": self.frames_with_truth, "frames_scored": len(p),
                "mpjpe_mm": round(float(mpjpe(p, g)) * 1000, 2), "pa_mpjpe_mm": round(float(pa_mpjpe(p, g)) * 1000, 2),
                "pck_10cm": round(float(pck(p, g, 0.1)), 4)}
