"""The skinning field at run time: skinning weights for any T-pose point set (onnxruntime).

For each point of a body in the canonical T-pose, its distances to the 22 T-pose joints (divided
by the leg length) go through a small MLP to 22 softmax weights (models/train/train_skinning.py).
No correspondences, no mesh topology: it weights meshes and point clouds alike, after which
live.body.skinning.lbs animates them. See docs/learned_retargeting.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import ModelError, UserInputError
from live.core.skeleton import NUM_JOINTS

DEFAULT_MODEL = assets.weight("skinning_field.onnx")


class SkinningFieldModel:
    """An exported skinning field. ``weights(points (N, 3), rest_joints (22, 3)) -> (N, 22)``."""

    def __init__(self, model_path: str | Path | None = None, threads: int = 1, chunk: int = 65536):
        from live.core.onnx import open_session

        self.path = Path(model_path) if model_path is not None else DEFAULT_MODEL
        self.session, self.card = open_session(self.path, threads=threads, what="skinning field",
                                               retrain="livecap train skinning")
        names = sorted(i.name for i in self.session.get_inputs())
        if names != ["joints", "points"]:
            raise ModelError(f"{self.path.name}: expected inputs points, joints; got {names}")
        card = self.path.with_suffix(".json")
        self.card: dict = json.loads(card.read_text()) if card.is_file() else {}
        self.chunk = int(chunk)

    def weights(self, points: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
        """Skinning weights (N, 22) float32, rows summing to 1, of T-pose points (N, 3) metres
        for a body whose T-pose joints are rest_joints (22, 3)."""
        pts = np.ascontiguousarray(np.asarray(points, np.float32))
        joints = np.ascontiguousarray(np.asarray(rest_joints, np.float32))
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise UserInputError(f"points must be (N, 3), got {pts.shape}")
        if joints.shape != (NUM_JOINTS, 3):
            raise UserInputError(f"rest joints must be (22, 3), got {joints.shape}")
        out = np.empty((len(pts), NUM_JOINTS), np.float32)
        for s in range(0, len(pts), self.chunk):  # bounded memory for big point clouds
            out[s:s + self.chunk] = self.session.run(None, {"points": pts[s:s + self.chunk], "joints": joints})[0]
        # Renormalise in float32 so rows sum to 1 within the body-file contract's tolerance.
        return out / out.sum(axis=1, keepdims=True)


def predict_weights(points: np.ndarray, rest_joints: np.ndarray, model_path: str | Path | None = None) -> np.ndarray:
    """One-shot: (N, 3) T-pose points and (22, 3) T-pose joints -> (N, 22) weights."""
    return SkinningFieldModel(model_path).weights(points, rest_joints)
