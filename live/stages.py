"""Pipeline stages and how the CLI assembles them.

The cloud stage turns each depth frame into a world-frame point cloud; the skeleton stage
(models.skeleton) and the retarget stage (live.retarget) join when their models are present.
"""

from __future__ import annotations

import numpy as np

from live.depth import points_to_world
from live.frames import FrameResult


class CloudStage:
    """Depth image or camera-frame cloud -> world-frame cloud (float32), kept on the result."""

    name = "cloud"

    def __init__(self) -> None:
        self.world_points: np.ndarray | None = None

    def process(self, result: FrameResult) -> bool:
        if result.depth is None:
            return False
        pts = result.depth.cloud()
        self.world_points = points_to_world(pts, result.depth.camera_to_world)
        result.latency_ms.setdefault("points", float(len(pts)))
        return len(pts) > 0
