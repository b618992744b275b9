"""The replay's result files: skeleton.npz, avatar.npz, avatar.bvh (contracts in CONVENTIONS.md).

``ResultsWriter`` is a sink. About once a second it appends the frames it holds to chunk files
in ``DIR/results.partial/`` and forgets them, so an open-ended run keeps little in memory and a
run that dies loses at most the last second; ``close`` assembles the final files from the chunks
and removes them. After a crash, ``assemble_results(DIR)`` (or ``python -m live.io.results DIR``)
writes the files from what the chunks hold. Files depend only on the frames' content (no wall-clock fields),
so two replays of a session give identical bytes, however the frames were chunked.

``read_skeleton`` / ``read_avatar`` load the final files and check them against the contract
(array names, shapes, dtypes): a file that breaks it raises FormatError.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.frames import FrameResult
from live.core.skeleton import NUM_JOINTS, PARENTS

PARTIAL_DIR = "results.partial"
_REST_FILE = "avatar_rest.npz"  # the avatar's rest joints and the frame rate, for avatar.bvh
#: avatar.bvh's rate when neither the source nor the frames tell (fewer than two frames).
DEFAULT_FPS = 30.0


def take_fps(t_ns: np.ndarray, default: float = DEFAULT_FPS) -> float:
    """A take's frame rate from its frame timestamps: one over the median interval (a dropped or
    late frame does not move it); ``default`` with fewer than two distinct timestamps."""
    steps = np.diff(np.asarray(t_ns, dtype=np.int64))
    steps = steps[steps > 0]
    return default if steps.size == 0 else 1e9 / float(np.median(steps))


# ----------------------------------------------------------------------------------- the contract
@dataclass(frozen=True)
class SkeletonResults:
    """skeleton.npz: the performer's skeleton per frame. t_ns (T,) int64; joints (T, 22, 3)
    float32 world metres; confidence (T, 22) float32; camera_to_world (T, 4, 4) float32 when
    the file stores the extrinsics each frame was solved in."""

    t_ns: np.ndarray
    joints: np.ndarray
    confidence: np.ndarray
    camera_to_world: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass(frozen=True)
class AvatarResults:
    """avatar.npz: the avatar's pose per frame. t_ns (T,) int64; rotations (T, 22, 4) float32
    local (w, x, y, z); root (T, 3) float32; joints (T, 22, 3) float32 world (NaN where not
    computed); rest_joints (22, 3) float32 and parents (22,) of the avatar."""

    t_ns: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    joints: np.ndarray
    rest_joints: np.ndarray
    parents: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


def _load_npz(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    # np.load fails on a foreign or damaged file with any of these, depending on the damage.
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise FormatError(f"not a readable .npz file ({exc})", path=str(path)) from exc
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise FormatError(f"missing arrays {', '.join(missing)}", path=str(path))
    return arrays


def _checked(path: Path, z: dict[str, np.ndarray], key: str, shape: tuple[int, ...], kind: str = "f") -> np.ndarray:
    """z[key] with the contract's shape and kind of dtype ("f" float -> float32, "i" integer ->
    int64)."""
    a = z[key]
    if a.shape != shape:
        raise FormatError(f"{key} is {a.shape}, expected {shape}", path=str(path))
    if kind == "f" and a.dtype.kind != "f":
        raise FormatError(f"{key} has dtype {a.dtype}, expected float32", path=str(path))
    if kind == "i" and a.dtype.kind not in "iu":
        raise FormatError(f"{key} has dtype {a.dtype}, expected int64", path=str(path))
    return a.astype(np.float32 if kind == "f" else np.int64, copy=False)


def _times(path: Path, z: dict[str, np.ndarray]) -> np.ndarray:
    t = z["t_ns"]
    if t.ndim != 1:
        raise FormatError(f"t_ns is {t.shape}, expected (T,)", path=str(path))
    return _checked(path, z, "t_ns", t.shape, "i")


def read_skeleton(path: str | Path) -> SkeletonResults:
    """DIR/skeleton.npz, checked against the contract (FormatError when it breaks it)."""
    path = Path(path)
    z = _load_npz(path, ("t_ns", "joints", "confidence"))
    t_ns = _times(path, z)
    n = len(t_ns)
    c2w = _checked(path, z, "camera_to_world", (n, 4, 4)) if "camera_to_world" in z else None
    return SkeletonResults(t_ns, _checked(path, z, "joints", (n, NUM_JOINTS, 3)),
                           _checked(path, z, "confidence", (n, NUM_JOINTS)), c2w)


def read_avatar(path: str | Path) -> AvatarResults:
    """DIR/avatar.npz, checked against the contract (FormatError when it breaks it)."""
    path = Path(path)
    z = _load_npz(path, ("t_ns", "rotations", "root", "joints", "rest_joints", "parents"))
    t_ns = _times(path, z)
    n = len(t_ns)
    parents = _checked(path, z, "parents", (NUM_JOINTS,), "i")
    if not np.array_equal(parents, PARENTS):
        raise FormatError("parents are not the canonical 22-joint skeleton's", path=str(path))
    return AvatarResults(t_ns, _checked(path, z, "rotations", (n, NUM_JOINTS, 4)), _checked(path, z, "root", (n, 3)),
                         _checked(path, z, "joints", (n, NUM_JOINTS, 3)),
                         _checked(path, z, "rest_joints", (NUM_JOINTS, 3)), parents)


# ----------------------------------------------------------------------------------- writing
def _write_skeleton(out: Path, t_ns: np.ndarray, joints: np.ndarray, confidence: np.ndarray,
                    camera_to_world: np.ndarray | None) -> Path:
    p = out / "skeleton.npz"
    arrays = {"t_ns": t_ns, "joints": joints, "confidence": confidence}
    if camera_to_world is not None and np.isfinite(camera_to_world).any():
        arrays["camera_to_world"] = camera_to_world  # absent when no skeleton came from a camera
    np.savez_compressed(p, allow_pickle=False, **arrays)
    return p


def _write_avatar(out: Path, t_ns: np.ndarray, rotations: np.ndarray, root: np.ndarray, joints: np.ndarray,
                  avatar_rest_joints: np.ndarray | None, fps: float,
                  joint_names: tuple[str, ...] | None = None) -> list[Path]:
    rest = (np.asarray(avatar_rest_joints, np.float32) if avatar_rest_joints is not None
            else np.zeros((22, 3), np.float32))
    p = out / "avatar.npz"
    np.savez_compressed(p, t_ns=t_ns, rotations=rotations, root=root, joints=joints, rest_joints=rest, parents=PARENTS)
    written = [p]
    if avatar_rest_joints is not None:
        from live.io.bvh_writer import write_canonical_bvh

        p = out / "avatar.bvh"
        write_canonical_bvh(p, rotations, root, rest, fps, names=joint_names)
        written.append(p)
    return written


#: camera_to_world of a skeleton that did not come from a camera (IMU suit, ground truth).
_NO_CAMERA = np.full((4, 4), np.nan, np.float32)


def _save_atomically(path: Path, **arrays: np.ndarray | np.generic) -> None:
    """An .npz that is either complete or absent, whenever the process dies."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez(f, allow_pickle=False, **arrays)
    os.replace(tmp, path)


def _chunks(partial: Path, stream: str) -> list[dict[str, np.ndarray]]:
    out = []
    for p in sorted(partial.glob(f"{stream}-[0-9]*.npz"), key=lambda p: int(p.stem.rpartition("-")[2])):
        with np.load(p, allow_pickle=False) as z:
            out.append({k: z[k] for k in z.files})
    return out


def _joined(chunks: list[dict[str, np.ndarray]], key: str) -> np.ndarray:
    return np.concatenate([c[key] for c in chunks])


def assemble_results(out_dir: str | Path) -> list[Path]:
    """Write skeleton.npz, avatar.npz (and avatar.bvh when the avatar's rest pose is known) from
    the chunks in DIR/results.partial/, then remove them; returns the files written. What a
    writer's close does, and after a crash what recovers all but about the last second."""
    out = Path(out_dir)
    partial = out / PARTIAL_DIR
    if not partial.is_dir():
        return []
    written = []
    skel = _chunks(partial, "skeleton")
    if skel:
        c2w = _joined(skel, "camera_to_world") if all("camera_to_world" in c for c in skel) else None
        written.append(_write_skeleton(out, _joined(skel, "t_ns"), _joined(skel, "joints"), _joined(skel, "confidence"),
                                       c2w))
    avatar = _chunks(partial, "avatar")
    if avatar:
        rest, fps, names = None, float("nan"), None
        if (partial / _REST_FILE).is_file():
            with np.load(partial / _REST_FILE, allow_pickle=False) as z:
                rest, fps = z["rest_joints"], float(z["fps"])
                if "joint_names" in z.files:
                    names = tuple(str(n) for n in z["joint_names"])
        t_ns = _joined(avatar, "t_ns")
        if not (np.isfinite(fps) and fps > 0):  # the source did not say: the frames' own rate
            fps = take_fps(t_ns)
        written += _write_avatar(out, t_ns, _joined(avatar, "rotations"), _joined(avatar, "root"),
                                 _joined(avatar, "joints"), rest, fps, names)
    shutil.rmtree(partial)
    return written


class ResultsWriter:
    """A sink writing DIR/skeleton.npz, DIR/avatar.npz and DIR/avatar.bvh (see the module).

    fps: the take's frame rate (avatar.bvh's Frame Time is 1 / fps), e.g. the depth stream's; None:
    from the avatar frames' timestamps (``take_fps``). avatar_joint_names: avatar.bvh's joint names
    (the avatar file's own bones, canonical order); None: the canonical names. flush_every_s: how often (wall clock,
    ``clock``) the frames held go to a chunk file."""

    def __init__(self, out_dir: str | Path, *, avatar_rest_joints: np.ndarray | None = None,
                 fps: float | None = None, avatar_joint_names: tuple[str, ...] | None = None,
                 flush_every_s: float = 1.0, clock: Callable[[], float] = time.monotonic):
        self.out = Path(out_dir)
        self.avatar_rest_joints = avatar_rest_joints
        self.fps = fps
        self.avatar_joint_names = avatar_joint_names
        self.flush_every_s = flush_every_s
        self._clock = clock
        self._last_flush: float | None = None
        self._chunks_written = 0
        self.skel_t: list[int] = []
        self.skel_joints: list[np.ndarray] = []
        self.skel_conf: list[np.ndarray] = []
        self.skel_c2w: list[np.ndarray] = []
        self.av_t: list[int] = []
        self.av_rot: list[np.ndarray] = []
        self.av_root: list[np.ndarray] = []
        self.av_joints: list[np.ndarray] = []
        self.written: list[Path] = []

    @property
    def partial(self) -> Path:
        return self.out / PARTIAL_DIR

    def send(self, result: FrameResult) -> None:
        if result.skeleton is not None:
            self.skel_t.append(result.skeleton.t_ns)
            self.skel_joints.append(np.asarray(result.skeleton.joints, np.float32))
            self.skel_conf.append(np.asarray(result.skeleton.confidence, np.float32))
            c2w = result.skeleton.camera_to_world
            self.skel_c2w.append(_NO_CAMERA if c2w is None else np.asarray(c2w, np.float32))
        if result.avatar is not None:
            a = result.avatar
            self.av_t.append(a.t_ns)
            self.av_rot.append(np.asarray(a.rotations, np.float32))
            self.av_root.append(np.asarray(a.root, np.float32))
            self.av_joints.append(np.asarray(a.joints, np.float32) if a.joints is not None
                                  else np.full((22, 3), np.nan, np.float32))
        now = self._clock()
        if self._last_flush is None:
            self._last_flush = now
        elif now - self._last_flush >= self.flush_every_s:
            self.flush()
            self._last_flush = now

    def flush(self) -> None:
        """The frames held so far to chunk files (then forgotten here)."""
        if not self.skel_t and not self.av_t:
            return
        if self._chunks_written == 0:
            # A new run: chunks another run left in this folder are not its frames.
            shutil.rmtree(self.partial, ignore_errors=True)
            self.partial.mkdir(parents=True)
            if self.avatar_rest_joints is not None:
                # The names go with the rest pose: a crashed run's recovered avatar.bvh keeps them.
                names = {} if self.avatar_joint_names is None else {
                    "joint_names": np.array(self.avatar_joint_names, dtype=np.str_)}
                _save_atomically(self.partial / _REST_FILE, rest_joints=np.asarray(self.avatar_rest_joints, np.float32),
                                 fps=np.float64(np.nan if self.fps is None else self.fps), **names)
        k = self._chunks_written
        if self.skel_t:
            _save_atomically(self.partial / f"skeleton-{k:06d}.npz", t_ns=np.asarray(self.skel_t, np.int64),
                             joints=np.stack(self.skel_joints), confidence=np.stack(self.skel_conf),
                             camera_to_world=np.stack(self.skel_c2w))
        if self.av_t:
            _save_atomically(self.partial / f"avatar-{k:06d}.npz", t_ns=np.asarray(self.av_t, np.int64),
                             rotations=np.stack(self.av_rot), root=np.stack(self.av_root),
                             joints=np.stack(self.av_joints))
        self._chunks_written += 1
        for held in (self.skel_t, self.skel_joints, self.skel_conf, self.skel_c2w, self.av_t, self.av_rot, self.av_root,
                     self.av_joints):
            held.clear()

    def close(self) -> None:
        """The last frames to a chunk, then the final files from all chunks."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.flush()
        if self._chunks_written:
            self.written += assemble_results(self.out)


if __name__ == "__main__":  # python -m live.io.results DIR: the result files a crashed run's chunks hold
    for target in sys.argv[1:] or ["."]:
        files = assemble_results(target)
        print(f"{target}: " + (", ".join(p.name for p in files) if files else f"no {PARTIAL_DIR}/ to recover"))
