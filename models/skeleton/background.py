"""A static background depth learned from person-free frames, to drop what never moves before the
person finder looks for clusters."""

from __future__ import annotations

import warnings

import numpy as np


class BackgroundModel:
    """A static background depth learned from person-free frames (per-pixel median)."""

    def __init__(self) -> None:
        self._frames: list[np.ndarray] = []
        self.depth_mm: np.ndarray | None = None

    def learn(self, depth_mm: np.ndarray) -> None:
        self._frames.append(np.asarray(depth_mm, np.uint16))
        stack = np.stack(self._frames[-30:]).astype(np.float32)
        stack[stack == 0] = np.nan
        with warnings.catch_warnings():  # pixels never seen are all-NaN: no background there
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(stack, axis=0)
        self.depth_mm = np.nan_to_num(med, nan=0.0).astype(np.uint16)

    def foreground(self, depth_mm: np.ndarray, margin_m: float, at: tuple[slice, slice] = (slice(None), slice(None))
                   ) -> np.ndarray:
        """Bool mask of the pixels ``depth_mm[at]`` clearly in front of the background (or where
        none was seen); ``at`` picks a strided crop so that only the pixels used are compared."""
        d = depth_mm[at].astype(np.int32)
        if self.depth_mm is None:
            return d > 0
        bg = self.depth_mm[at].astype(np.int32)
        return (d > 0) & ((bg == 0) | (d < bg - int(margin_m * 1000)))
