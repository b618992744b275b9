"""The replay's result files: skeleton.npz, avatar.npz, avatar.bvh (contracts in CONVENTIONS.md).

A sink that keeps every result's arrays and writes them when closed. Files depend only on the
frames' content (no wall-clock fields), so two replays of a session give identical bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from live.core.frames import FrameResult
from live.core.skeleton import PARENTS


class ResultsWriter:
    def __init__(self, out_dir: str | Path, *, avatar_rest_joints: np.ndarray | None = None,
                 fps: float = 30.0):
        self.out = Path(out_dir)
        self.avatar_rest_joints = avatar_rest_joints
        self.fps = fps
        self.skel_t: list[int] = []
        self.skel_joints: list[np.ndarray] = []
        self.skel_conf: list[np.ndarray] = []
        self.av_t: list[int] = []
        self.av_rot: list[np.ndarray] = []
        self.av_root: list[np.ndarray] = []
        self.av_joints: list[np.ndarray] = []
        self.written: list[Path] = []

    def send(self, result: FrameResult) -> None:
        if result.skeleton is not None:
            self.skel_t.append(result.skeleton.t_ns)
            self.skel_joints.append(np.asarray(result.skeleton.joints, np.float32))
            self.skel_conf.append(np.asarray(result.skeleton.confidence, np.float32))
        if result.avatar is not None:
            a = result.avatar
            self.av_t.append(a.t_ns)
            self.av_rot.append(np.asarray(a.rotations, np.float32))
            self.av_root.append(np.asarray(a.root, np.float32))
            self.av_joints.append(np.asarray(a.joints, np.float32) if a.joints is not None
                                  else np.full((22, 3), np.nan, np.float32))

    def close(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        if self.skel_t:
            p = self.out / "skeleton.npz"
            np.savez_compressed(p, t_ns=np.asarray(self.skel_t, np.int64), joints=np.stack(self.skel_joints),
                                confidence=np.stack(self.skel_conf))
            self.written.append(p)
        if self.av_t:
            rest = (np.asarray(self.avatar_rest_joints, np.float32) if self.avatar_rest_joints is not None
                    else np.zeros((22, 3), np.float32))
            rotations, root = np.stack(self.av_rot), np.stack(self.av_root)
            p = self.out / "avatar.npz"
            np.savez_compressed(p, t_ns=np.asarray(self.av_t, np.int64), rotations=rotations, root=root,
                                joints=np.stack(self.av_joints), rest_joints=rest, parents=PARENTS)
            self.written.append(p)
            if self.avatar_rest_joints is not None:
                from live.io.bvh import write_canonical_bvh

                p = self.out / "avatar.bvh"
                write_canonical_bvh(p, rotations, root, rest, self.fps)
                self.written.append(p)
