"""Self-contacts around any retargeter: ``ContactRetargeter(inner, ...)`` is a Retargeter too.

Per frame: the inner retargeter (analytic or learned, its foot placement included) poses the
avatar; the performer's pose is solved to global rotations on its rest skeleton, its contacts are
found on its body surface (live/retarget/contacts_self.py), and the avatar's arms are corrected on
the avatar's own surface (live/retarget/contacts_keep.py). Only the arms' rotations change, and
only on frames where a hand or forearm is near the body; other joints keep the inner
retargeter's exact output.

The performer's surface is a body mesh placed on the performer's rest skeleton: the true body of
a synthetic session, or else ``fitted_performer``: of the template bodies, the one whose
proportions are nearest the estimated skeleton, resized to it. A skeleton says nothing about
girth, so the template is of average build.
"""

from __future__ import annotations

import numpy as np

from live.core.errors import UserInputError
from live.core.frames import AvatarPose, GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics_matrices, local_matrices
from live.core.rotations import matrix_to_quat, quat_to_matrix
from live.core.skeleton import NUM_JOINTS, pelvis_height
from live.core.timing import FrameClock, frame_interval_s
from live.retarget.analytic import LIMBS, RestInfo, solve_globals
from live.retarget.contacts_keep import ContactKeeper
from live.retarget.contacts_self import ContactSettings, SelfContactDetector, SourceContacts
from live.retarget.contacts_surface import BodySurface, body_surface
from live.retarget.interface import Retargeter, step_frame

#: Bodies of average build a performer's surface is fitted from (training bodies of the library:
#: the held-out ones stay unseen by every evaluation of the performer's side).
PERFORMER_TEMPLATES = ("androgynous_adult", "child_boy_9y")


def _proportions(rest: np.ndarray) -> np.ndarray:
    rest = np.asarray(rest, np.float64)
    return (rest - rest[0]) / pelvis_height(rest)


class PerformerSurfaces:
    """The template bodies' surfaces, built (or read from the cache) once; ``fitted(rest)`` picks
    the template nearest in proportions and resizes it to ``rest``."""

    def __init__(self, templates: tuple[str, ...] = PERFORMER_TEMPLATES):
        from live.body.library import load_body

        bodies = [load_body(name) for name in templates]
        self.surfaces = [body_surface(b) for b in bodies]
        self.proportions = [_proportions(b.rest_joints) for b in bodies]

    def fitted(self, rest_joints: np.ndarray) -> BodySurface:
        mine = _proportions(rest_joints)
        best = int(np.argmin([np.abs(mine - p).sum() for p in self.proportions]))
        return self.surfaces[best].fitted(rest_joints)


class ContactRetargeter:
    """A Retargeter (live/retarget/interface.py) that keeps self-contacts on the avatar.

    inner: the retargeter to wrap; target: the avatar's surface (``body_surface(avatar)``);
    source_rest: the performer's rest skeleton; performer: the performer's surface on its own
    rest skeleton (a ``BodySurface``, resized to each new rest skeleton) or a
    ``PerformerSurfaces`` to fit from. fps: the frame rate assumed when ``step`` has no dt."""

    def __init__(self, inner: Retargeter, target: BodySurface, target_rest: np.ndarray, source_rest: np.ndarray,
                 performer: BodySurface | PerformerSurfaces, *, fps: float = 30.0,
                 settings: ContactSettings = ContactSettings()):
        self.settings = settings
        self.inner = inner
        self.target = target
        self.performer = performer
        self.dt = frame_interval_s(fps)
        self.clock = FrameClock()
        target_rest = np.asarray(target_rest, np.float64)
        self.keeper = ContactKeeper(RestInfo.of(target_rest).offsets, settings)
        # Only the performer's contacts the keeper holds are measured (not the forearms': their
        # contacts weigh nothing, forearms are only kept out of the avatar's body).
        self.detector = SelfContactDetector(settings, self.keeper.held_probes)
        self.set_source_rest(source_rest)
        self.reset()

    def set_source_rest(self, rest_joints: np.ndarray) -> None:
        """New performer proportions: passed to the inner retargeter, the performer's surface resized."""
        self.inner.set_source_rest(rest_joints)
        self.source = RestInfo.of(rest_joints)
        self.source_surface = self.performer.fitted(rest_joints)

    def reset(self) -> None:
        self.inner.reset()
        self.detector.reset()
        self.keeper.reset()
        self.clock.reset()
        self.twist = np.zeros(len(LIMBS))
        self.last_globals: np.ndarray | None = None
        self.last_contacts: SourceContacts | None = None
        self.counters = {"frames_with_hand_contacts": 0, "frames_corrected": 0}

    def step(self, pose: np.ndarray, root: np.ndarray | None = None, dt: float | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Retarget one frame (as the inner retargeter's ``step``) and keep its contacts."""
        pose = np.asarray(pose, np.float64)
        root_t, quats, joints = self.inner.step(pose, root, dt)
        dt = self.dt if dt is None else dt
        if pose.shape == (NUM_JOINTS, 4):
            if root is None:
                raise UserInputError("rotations need a root position")
            src_pos, src_glob = forward_kinematics_matrices(quat_to_matrix(pose)[None], np.asarray(root, np.float64)[None],
                                                            self.source.offsets)
            src_pos, src_glob = src_pos[0], src_glob[0]
        else:
            # The analytic retargeter has solved the performer's rotations already.
            src_glob = getattr(self.inner, "last_source_globals", None)
            if src_glob is None:
                src_glob_b, _, self.twist = solve_globals(pose[None], self.source, self.twist)
                src_glob = src_glob_b[0]
            src_pos = pose
        contacts = self.detector.update(self.source_surface, src_glob, src_pos, dt)
        self.last_contacts = contacts
        if contacts.hand_contacts:
            self.counters["frames_with_hand_contacts"] += 1
        glob = np.array(self.inner.last_globals, np.float64)
        loc = local_matrices(glob)
        pos = np.array(joints, np.float64)
        changed = self.keeper(self.target, glob, loc, pos, contacts, dt)
        self.last_globals = glob
        if not changed:
            return root_t, quats, joints
        self.counters["frames_corrected"] += 1
        quats = np.array(quats, np.float64)
        idx = sorted(changed)
        quats[idx] = matrix_to_quat(loc[idx])
        return root_t, quats, pos

    def process(self, frame: SkeletonFrame | GroundTruth) -> AvatarPose:
        """Retarget a SkeletonFrame (joints) or GroundTruth (rotations + root); dt from t_ns."""
        return step_frame(self.step, frame, self.clock.tick(frame.t_ns))
