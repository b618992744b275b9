"""VMC protocol output: livecap as a "performer" puppeteering a "marionette" over OSC/UDP.

VMC (https://protocol.vmc.info) is OSC over UDP. Every frame becomes one OSC bundle (timetag
"immediately") holding, in this order:

    /VMC/Ext/OK        i loaded, i calibration state, i calibration mode, i tracking status
    /VMC/Ext/T         f time in seconds (since this sink's first frame)
    /VMC/Ext/Root/Pos  s "root", f px, py, pz, f qx, qy, qz, qw
    /VMC/Ext/Bone/Pos  s bone,   f px, py, pz, f qx, qy, qz, qw      (x 22, canonical order)
    /VMC/Ext/Bone/Pos  s bone,   f px, py, pz, f 0, 0, 0, 1          (each extra bone, at rest)

A VRM / glTF avatar's rig (the Body's ``rig``, live/body/gltf_rig.py) replaces the 22 canonical
bones by the file's own: each bone it has, under its own HumanBodyBones name (a file without an
upperChest sends its chest as Chest), with the local position and rotation of its own node for its
own rest frame (identity at rest for a normalised VRM 0.x, its rest rotation for a VRM 1.0 or a
rolled bone), then its fingers, eyes and jaw at rest, so a receiver applying every bone it is sent
to the file's own nodes rebuilds the avatar's pose. Without a rig, ``extra_bones`` are sent at
rest after the 22, identity localRotation and the file's rest offset as localPosition.
(Godette's frame, 21 body bones and 24 finger bones, is 3,808 bytes: ``--vmc-mtu`` splits it.)

With ``max_bundle_bytes`` (``--vmc-mtu``) a frame's messages are split, in order, over as many
bundles as keep each datagram within that size (a 22-bone frame is ~1,850 bytes: over Ethernet's
1,500-byte MTU it travels as IP fragments, and one lost fragment loses the frame).

Positions and rotations are Unity's (left-handed, see live/outputs/unity.py). Bone values are
Unity *local* values (Transform.localPosition / localRotation): the rotation is our canonical
local rotation (identity = T-pose, as normalised humanoids expect), the position is the rest
offset from the parent bone. Like VirtualMotionCapture, the root transform stays at the origin
and the body's motion travels in the Hips bone: its position is the pelvis world position.

The sink is a UDP client only: it never binds a port, and sends only to the host and port it is
given. Its socket is connected to that address: the kernel picks the local interface that routes
there (127.0.0.1 for a local app) and drops datagrams from anyone else, so nothing reaches the
process from the network. A receiver that is not running yet answers with ICMP "port
unreachable"; those refusals are counted (``refused``), not treated as errors. Shapes: root (3,), rotations (22, 4) (w, x, y, z), rest_joints (22, 3).
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder

from live.body.body import ExtraBone
from live.body.gltf_rig import AvatarRig
from live.core.errors import UserInputError
from live.core.frames import FrameResult
from live.core.rotations import quat_identity, quat_multiply, quat_normalize, quat_rotate
from live.core.skeleton import NUM_JOINTS, default_rest_joints, rest_offsets
from live.outputs.unity import (
    JOINT_TO_UNITY_BONE,
    UNITY_BONE_INDEX,
    UNITY_BONES,
    UNITY_EXTRA_BONES,
    position_from_unity,
    position_to_unity,
    quat_from_unity,
    quat_to_unity,
)

log = logging.getLogger(__name__)

ADDR_OK = "/VMC/Ext/OK"
ADDR_TIME = "/VMC/Ext/T"
ADDR_ROOT = "/VMC/Ext/Root/Pos"
ADDR_BONE = "/VMC/Ext/Bone/Pos"

# /VMC/Ext/OK values (protocol.vmc.info): loaded 1 = avatar loaded; calibration state
# 3 = calibrated; calibration mode 0 = normal; tracking status 1 = good, 0 = poor.
OK_LOADED = 1
CALIBRATION_CALIBRATED = 3
CALIBRATION_MODE_NORMAL = 0

DEFAULT_PORT = 39539


@dataclass(frozen=True, slots=True)
class VmcPose:
    """A pose as a VMC receiver rebuilds it, in our conventions: root (3,) pelvis world position,
    rotations (22, 4) local (w, x, y, z), t_s seconds, tracking_ok."""

    root: np.ndarray
    rotations: np.ndarray
    t_s: float
    tracking_ok: bool


def vmc_messages(
    root: np.ndarray,
    rotations: np.ndarray,
    rest_joints: np.ndarray,
    t_s: float,
    tracking_ok: bool = True,
    extra_bones: Sequence[ExtraBone] = (),
    rig: AvatarRig | None = None,
) -> list[tuple[str, list]]:
    """One frame as (address, args) pairs, in bundle order (see the module docstring).

    root (3,) pelvis world position; rotations (22, 4) local (w, x, y, z); rest_joints (22, 3);
    extra_bones: sent at rest after the 22 (``extra_bone_messages``); rig: a VRM / glTF avatar's
    own bones (``rig_bone_messages``), sent instead of the 22 canonical bones and extra_bones.
    """
    rotations = quat_normalize(np.asarray(rotations, dtype=np.float64))
    if rotations.shape != (NUM_JOINTS, 4):
        raise UserInputError(f"VMC needs (22, 4) rotations, got {rotations.shape}")
    head: list[tuple[str, list]] = [
        (ADDR_OK, [OK_LOADED, CALIBRATION_CALIBRATED, CALIBRATION_MODE_NORMAL, int(bool(tracking_ok))]),
        (ADDR_TIME, [float(t_s)]),
        (ADDR_ROOT, ["root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
    ]
    if rig is not None:
        return head + rig_bone_messages(rig, root, rotations)
    offsets = rest_offsets(np.asarray(rest_joints, dtype=np.float64))
    offsets[0] = np.asarray(root, dtype=np.float64)  # Hips carries the pelvis world position
    pos_u = position_to_unity(offsets)
    rot_u = quat_to_unity(rotations)
    msgs = head
    for j, bone in enumerate(UNITY_BONES):
        msgs.append((ADDR_BONE, [bone, *map(float, pos_u[j]), *map(float, rot_u[j])]))
    return msgs + extra_bone_messages(extra_bones)


def rig_bone_messages(rig: AvatarRig, root: np.ndarray, rotations: np.ndarray) -> list[tuple[str, list]]:
    """Bone messages for a VRM / glTF avatar's own bones (live/body/gltf_rig.py): each bone the file
    maps, under its own HumanBodyBones name (a file without an upperChest gets its chest as Chest),
    its local position and rotation for its own rest frame and transform parent (a normalised VRM
    0.x: identity at rest; a VRM 1.0 or a rolled bone: its own rest rotation), in Unity's frame."""
    pos, rot = rig.bone_values(root, rotations)
    pos_u, rot_u = position_to_unity(pos), quat_to_unity(rot)
    return [(ADDR_BONE, [name, *map(float, pos_u[i]), *map(float, rot_u[i])]) for i, name in enumerate(rig.names)]


def extra_bone_messages(extra_bones: Sequence[ExtraBone]) -> list[tuple[str, list]]:
    """Bone messages for an avatar's bones beyond the 22, at rest: identity localRotation, the rest
    offset from the parent as localPosition (Unity's frame). Each bone must be a HumanBodyBones
    name of UNITY_EXTRA_BONES, once, and hang from a canonical joint or an extra bone listed before it."""
    msgs: list[tuple[str, list]] = []
    seen: set[str] = set()
    for bone in extra_bones:
        if bone.name not in UNITY_EXTRA_BONES or bone.name in seen:
            raise UserInputError(f"VMC extra bone {bone.name!r} is not a HumanBodyBones finger, eye or jaw bone, "
                                 "or is given twice")
        if bone.parent not in JOINT_TO_UNITY_BONE and bone.parent not in seen:
            raise UserInputError(f"VMC extra bone {bone.name!r} hangs from {bone.parent!r}, neither a joint nor an "
                                 "extra bone before it")
        seen.add(bone.name)
        pos_u = position_to_unity(np.asarray(bone.offset, dtype=np.float64))
        msgs.append((ADDR_BONE, [bone.name, *map(float, pos_u), 0.0, 0.0, 0.0, 1.0]))
    return msgs


#: Bytes an OSC bundle takes besides its messages ("#bundle\0" and the timetag), and per message
#: (its int32 size).
_BUNDLE_HEADER, _ELEMENT_HEADER = 16, 4
#: The smallest --vmc-mtu: room for the largest message of a frame (a bone's, ~80 bytes) and more.
MIN_BUNDLE_BYTES = 256
MAX_BUNDLE_BYTES = 65507  # the largest UDP payload over IPv4


def _build_message(address: str, args: list):
    msg = OscMessageBuilder(address=address)
    for a in args:
        kind = "s" if isinstance(a, str) else "i" if isinstance(a, (int, np.integer)) else "f"
        msg.add_arg(a, kind)
    return msg.build()


def encode_bundle(messages: Sequence[tuple[str, list]]) -> bytes:
    """(address, args) pairs -> one OSC bundle datagram; ints as 'i', floats as float32 'f'."""
    bundle = OscBundleBuilder(IMMEDIATELY)
    for address, args in messages:
        bundle.add_content(_build_message(address, args))
    return bundle.build().dgram


def encode_bundles(messages: Sequence[tuple[str, list]], max_bytes: int | None = None) -> list[bytes]:
    """(address, args) pairs -> OSC bundle datagrams of at most max_bytes each (None: one bundle),
    messages kept in order, so a frame fits one network MTU (a 22-bone frame is ~1,850 bytes,
    above Ethernet's 1,500: one lost IP fragment would lose the whole frame). The first bundle
    starts with /VMC/Ext/OK, as receivers expect."""
    if max_bytes is None:
        return [encode_bundle(messages)]
    if not MIN_BUNDLE_BYTES <= max_bytes <= MAX_BUNDLE_BYTES:
        raise UserInputError(f"VMC bundle size must be in {MIN_BUNDLE_BYTES}..{MAX_BUNDLE_BYTES} bytes, got {max_bytes}")
    out: list[bytes] = []
    bundle, size = OscBundleBuilder(IMMEDIATELY), _BUNDLE_HEADER
    for address, args in messages:
        msg = _build_message(address, args)
        need = _ELEMENT_HEADER + msg.size
        if size + need > max_bytes and size > _BUNDLE_HEADER:
            out.append(bundle.build().dgram)
            bundle, size = OscBundleBuilder(IMMEDIATELY), _BUNDLE_HEADER
        bundle.add_content(msg)
        size += need
    out.append(bundle.build().dgram)
    return out


def pose_from_vmc(
    bones: Mapping[str, Sequence[float]],
    root: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    t_s: float = 0.0,
    tracking_ok: bool = True,
) -> VmcPose:
    """Rebuild our pose from received VMC values (the receiver side, for tests and tools).

    bones: Unity bone name -> (px, py, pz, qx, qy, qz, qw) local values; root: the Root/Pos
    values. Bones that were not received keep the identity (T-pose) rotation.
    """
    rotations = quat_identity((NUM_JOINTS,))
    for name, values in bones.items():
        j = UNITY_BONE_INDEX.get(name)
        if j is not None:
            rotations[j] = quat_from_unity(np.asarray(values[3:7], dtype=np.float64))
    root_pos = np.asarray(root[:3], dtype=np.float64)
    root_rot = quat_from_unity(np.asarray(root[3:7], dtype=np.float64))
    hips = np.asarray(bones.get("Hips", (0.0, 0.0, 0.0))[:3], dtype=np.float64)
    # World Hips = root_pos + R_root hips in Unity's frame; mirroring it term by term gives
    # M root_pos + (M R_root M)(M hips), with M R_root M the root rotation in our frame.
    pelvis = position_from_unity(root_pos) + quat_rotate(root_rot, position_from_unity(hips))
    # The pelvis's world rotation also includes the root's, when a sender rotates the root.
    rotations[0] = quat_multiply(root_rot, rotations[0])
    return VmcPose(root=pelvis, rotations=rotations, t_s=float(t_s), tracking_ok=bool(tracking_ok))


class VmcSink:
    """Sends each FrameResult's avatar pose as one VMC bundle to host:port (UDP client only).

    rate_hz caps the send rate (frames arriving faster are coalesced: the latest frame due is
    sent, the others are dropped and counted); rate_hz=None sends every frame. A frame held
    back by the rate limit is delivered at the next due send() or at close().
    Never raises from send(); errors are counted in ``errors`` and logged.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        rate_hz: float | None = 60.0,
        avatar_rest_joints: np.ndarray | None = None,
        min_confidence: float = 0.3,
        clock: Callable[[], float] = time.monotonic,
        max_bundle_bytes: int | None = None,
        extra_bones: Sequence[ExtraBone] = (),
        rig: AvatarRig | None = None,
    ) -> None:
        if not host:
            raise UserInputError("VMC needs a host name or address to send to")
        if not 0 < int(port) < 65536:
            raise UserInputError(f"VMC port must be in 1..65535, got {port}")
        if rate_hz is not None and not rate_hz > 0:
            raise UserInputError(f"VMC rate must be > 0 Hz or None, got {rate_hz}")
        if max_bundle_bytes is not None and not MIN_BUNDLE_BYTES <= int(max_bundle_bytes) <= MAX_BUNDLE_BYTES:
            raise UserInputError(f"VMC bundle size (--vmc-mtu) must be in {MIN_BUNDLE_BYTES}..{MAX_BUNDLE_BYTES} "
                                 f"bytes, got {max_bundle_bytes}")
        self.max_bundle_bytes = None if max_bundle_bytes is None else int(max_bundle_bytes)
        rest = default_rest_joints() if avatar_rest_joints is None else np.asarray(avatar_rest_joints)
        if rest.shape != (NUM_JOINTS, 3):
            raise UserInputError(f"avatar rest joints must be (22, 3), got {rest.shape}")
        try:
            # Resolve once; the socket is never bound explicitly (the OS picks the source port).
            family, _, _, _, self._address = socket.getaddrinfo(host, int(port), type=socket.SOCK_DGRAM)[0]
        except OSError as e:  # an unresolvable host name
            raise UserInputError(f"cannot send VMC to {host}:{port}: {e}") from e
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.connect(self._address)
        except OSError as e:  # e.g. no route to the host
            self._sock.close()
            raise UserInputError(f"cannot send VMC to {host}:{port}: {e}") from e
        self.host, self.port = host, int(port)
        self._rest = rest.astype(np.float64)
        self._extra = tuple(extra_bones)
        self._rig = rig
        extra_bone_messages(self._extra)  # a bad bone is refused here, not on every frame
        self._period = None if rate_hz is None else 1.0 / float(rate_hz)
        self._min_conf = float(min_confidence)
        self._clock = clock
        self._next_due = -np.inf
        self._pending: FrameResult | None = None
        self._t0_ns: int | None = None
        self._closed = False
        self.sent = 0        # frames sent (one bundle each, or several under max_bundle_bytes)
        self.bundles = 0     # datagrams sent
        self.coalesced = 0   # frames replaced by a newer one before their turn
        self.skipped = 0     # frames without an avatar pose
        self.refused = 0     # bundles the receiver's host refused (no app listening yet)
        self.errors = 0

    def send(self, result: FrameResult) -> None:
        if self._closed:
            return
        try:
            if result.avatar is None:
                self.skipped += 1
                return
            if self._period is None:
                self._transmit(result)
                return
            now = self._clock()
            if now < self._next_due:
                if self._pending is not None:
                    self.coalesced += 1
                self._pending = result
                return
            if self._pending is not None:
                self.coalesced += 1  # the held frame is older than this one
                self._pending = None
            self._transmit(result)
            # Keep the phase of the schedule, but do not burst to catch up after a pause.
            self._next_due = now + self._period if now - self._next_due >= self._period else self._next_due + self._period
        except Exception as e:  # a sink must never take the pipeline down
            self._error(e)

    def close(self) -> None:
        if self._closed:
            return
        try:
            if self._pending is not None:
                self._transmit(self._pending)
                self._pending = None
        except Exception as e:
            self._error(e)
        finally:
            self._closed = True
            self._sock.close()

    name = "vmc"

    def stats(self) -> dict[str, int]:
        return {"sent": self.sent, "bundles": self.bundles, "coalesced": self.coalesced, "skipped": self.skipped,
                "refused": self.refused, "errors": self.errors}

    @property
    def counters(self) -> dict[str, int]:
        """Frames sent, datagrams (bundles) sent, frames coalesced by the rate limit, frames without a pose, bundles the
        receiver's host refused, errors: stats.json's ``sinks.vmc.counters``."""
        return self.stats()

    @property
    def details(self) -> dict[str, object]:
        return {"address": f"{self.host}:{self.port}", "rate_hz": None if self._period is None else 1.0 / self._period,
                "max_bundle_bytes": self.max_bundle_bytes}

    def __enter__(self) -> VmcSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _transmit(self, result: FrameResult) -> None:
        if self._t0_ns is None:
            self._t0_ns = result.t_ns
        # Seconds since the first frame: absolute monotonic seconds would lose float32 precision.
        t_s = (result.t_ns - self._t0_ns) * 1e-9
        tracking_ok = True
        if result.skeleton is not None:
            tracking_ok = float(np.mean(result.skeleton.confidence)) >= self._min_conf
        avatar = result.avatar
        msgs = vmc_messages(avatar.root, avatar.rotations, self._rest, t_s, tracking_ok, self._extra, self._rig)
        for datagram in encode_bundles(msgs, self.max_bundle_bytes):
            try:
                self._sock.send(datagram)
            except ConnectionRefusedError:
                # The ICMP answer to an earlier bundle: nobody listens there (yet). VMC apps start
                # and stop independently of the performer; the next frames go out as usual.
                self.refused += 1
                return
            self.bundles += 1
        self.sent += 1

    def _error(self, e: Exception) -> None:
        self.errors += 1
        if self.errors == 1 or self.errors % 100 == 0:
            log.warning("VMC sink to %s:%d: %s (%d errors so far)", self.host, self.port, e, self.errors)
