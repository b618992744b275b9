"""A sink that scores the performer's skeleton against ground truth when a session has it."""

from __future__ import annotations

import numpy as np

from live.frames import FrameResult
from live.metrics import mpjpe, pa_mpjpe, pck


class AccuracySink:
    def __init__(self) -> None:
        self.pred: list[np.ndarray] = []
        self.gt: list[np.ndarray] = []
        self.frames_with_truth = 0

    def send(self, result: FrameResult) -> None:
        if result.truth is None or result.truth.t_ns != result.t_ns:
            return
        self.frames_with_truth += 1
        if result.skeleton is not None:
            self.pred.append(np.asarray(result.skeleton.joints, np.float64))
            self.gt.append(np.asarray(result.truth.joints, np.float64))

    def close(self) -> None:
        pass

    def summary(self) -> dict:
        if not self.pred:
            return {"frames_with_truth": self.frames_with_truth, "frames_scored": 0}
        p, g = np.stack(self.pred), np.stack(self.gt)
        return {"frames_with_truth": self.frames_with_truth, "frames_scored": len(p),
                "mpjpe_mm": round(float(mpjpe(p, g)) * 1000, 2), "pa_mpjpe_mm": round(float(pa_mpjpe(p, g)) * 1000, 2),
                "pck_10cm": round(float(pck(p, g, 0.1)), 4)}
