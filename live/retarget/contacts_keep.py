"""Self-contacts kept on the avatar and hands and forearms kept out of its body, one frame at a time.

After any retargeter (rotation copy or the network), on the avatar's own surface
(live/retarget/contacts_surface.py), for both arms at once:

1. **Goals.** Every region near a hand (the other hand and arm, head, torso, legs) gets a gap
   goal: where the performer is in contact with it (weight w from live/retarget/contacts_self.py),
   the performer's gap, at least ``margin``; elsewhere only a floor, min(the performer's gap,
   ``clearance``) and at least ``margin`` (no sinking in, no touching where the performer does
   not; a hand in contact somewhere keeps only the margin from the rest). Forearms keep the
   margin. The residual w (goal - gap) + (1 - w) max(0, floor - gap) acts along the region's
   outward direction; between the two arms each closes half of it.
2. **Steps.** Damped Gauss-Newton per arm on the hand's translation (the hand keeps its
   orientation: a contact lands where the rotation copy put the hand in the part's frame, moved
   onto the avatar's skin at the performer's gap) and the elbow's swivel about the
   shoulder-wrist line (moves the forearm, leaves the hand); a forearm point moves with a
   fraction of the hand's translation. The wrist reaches its place by two-bone IK (the hand's
   world orientation kept); out of reach, the collar turns toward it (at most ``collar_deg``).
3. **In time.** Each frame starts from the last frame's correction, let go with ``release_s``
   (also the prior the steps are damped toward); at most _ITERATIONS steps, a step turning back
   on the last one halved; the correction's change is rate-limited. It follows the motion
   continuously and, with nothing left to keep, fades out. A frame with nothing near is left
   exactly as the retargeter made it.
"""

from __future__ import annotations

import math

import numpy as np

from live.core import vec3 as v3
from live.core.skeleton import JOINT_INDEX, PARENTS
from live.retarget.analytic import LIMBS
from live.retarget.contacts_self import ContactSettings, SourceContacts
from live.retarget.contacts_surface import PROBES, REGIONS, BodySurface, Gaps, measure
from live.retarget.ik import limb_ik

#: Gauss-Newton steps per frame at most (each measures the gaps once).
_ITERATIONS = 2
#: Weight of the prior (the last frame's correction, let go) against the residuals: on the hand
#: translation (m^2 per m^2) and the swivel (m^2 per rad^2). Small: the goals win, the prior
#: only steadies what they leave free and damps the steps.
_PRIOR = np.diag([1e-3, 1e-3, 1e-3, 4e-3])
#: Largest hand move (m) and elbow swivel (rad) in one frame, and in one step.
MAX_HAND_MOVE = 0.25
MAX_SWIVEL = math.radians(60.0)
MAX_STEP = 0.05
#: A step smaller than this (m, rad) ends the frame's iterations.
SETTLED_STEP = 0.004
SETTLED_SWIVEL = math.radians(1.0)
MAX_SWIVEL_STEP = math.radians(15.0)
#: Weight of a forearm's contacts against a hand's: none. Viewers notice them much less, and a
#: forearm held to a hip fights the hand's own goals where bodies differ most; forearms are only
#: kept out of the body.
FOREARM_CONTACT_WEIGHT = 0.0
#: How fast the correction may change: hand translation (m/s) and swivel (rad/s). A frame's goals
#: can jump (a contact starts, a hand slips between thigh and belly); the arm follows smoothly.
MAX_HAND_SPEED = 0.8
MAX_SWIVEL_SPEED = math.radians(180.0)


class _Arm:
    """The joints and probe sets of one arm."""

    def __init__(self, side: str):
        limb = LIMBS[2] if side == "left" else LIMBS[3]
        self.side = side
        self.collar = JOINT_INDEX[f"{side}_collar"]
        self.shoulder, self.elbow, self.wrist = (int(j) for j in limb[:3])
        self.hinge_axis = tuple(float(x) for x in limb[3])
        self.hand = next(i for i, p in enumerate(PROBES) if p.name == f"{side}_hand")
        self.forearm = next(i for i, p in enumerate(PROBES) if p.name == f"{side}_forearm")
        self.joints = [self.collar, self.shoulder, self.elbow, self.wrist]


ARMS = (_Arm("left"), _Arm("right"))
_ALL = np.arange(len(PROBES))


class ContactKeeper:
    """Keeps the performer's contacts on the avatar and its hands and forearms out of its body.

    offsets: the avatar's rest offsets (22, 3); settings: as the detector's. ``__call__`` changes
    one frame's global and local rotations and joints in place and returns the joints it
    rotated (a set, empty when nothing was near)."""

    def __init__(self, offsets: np.ndarray, settings: ContactSettings = ContactSettings(),
                 collar_deg: float = 15.0):
        self.offsets = np.asarray(offsets, np.float64)
        for arm in ARMS:
            arm.offsets = (self.offsets[arm.elbow].tolist(), self.offsets[arm.wrist].tolist())
        self.settings = settings
        self.max_collar = math.radians(collar_deg)
        self.release_s = settings.blend_s
        self.reset()
        s = settings
        hands = np.array([p.kind == "hand" for p in PROBES])
        # Per probe set: how far to look, the most a floor asks, the weight of its contacts.
        self._reach = np.where(hands, max(s.reach, s.clearance), s.reach) + s.margin
        self._floor_cap = np.where(hands, max(s.clearance, s.margin), s.margin)
        self._contact_weight = np.where(hands, 1.0, FOREARM_CONTACT_WEIGHT)
        # Rows between the two arms: each arm closes half of the gap.
        self._shared = np.zeros((len(PROBES), len(REGIONS)), bool)
        for i, p in enumerate(PROBES):
            other = "right" if p.side == "left" else "left"
            self._shared[i, [REGIONS.index(f"{other}_hand"), REGIONS.index(f"{other}_arm")]] = True

    def residuals(self, gaps: Gaps, source: SourceContacts) -> np.ndarray:
        """Each row's residual (m, along its direction): the performer's gap where in contact
        (weighted), elsewhere the floor (not closer than min(performer's gap, clearance), never
        within margin); halved between the arms. A hand in contact somewhere only keeps the
        margin from the rest: between a heavy avatar's thigh and belly there may be no room for
        more."""
        s = self.settings
        src_gap = source.gap[gaps.probe, gaps.region]
        w = source.weight[gaps.probe, gaps.region] * self._contact_weight[gaps.probe]
        busy = (source.weight * self._contact_weight[:, None]).max(1)[gaps.probe]
        cap = self._floor_cap[gaps.probe] * (1.0 - busy) + s.margin * busy
        goal = np.maximum(src_gap, s.margin)
        floor = np.clip(src_gap, s.margin, np.maximum(cap, s.margin))
        residual = w * (goal - gaps.gap) + (1.0 - w) * np.maximum(floor - gaps.gap, 0.0)
        return np.where(self._shared[gaps.probe, gaps.region], 0.5 * residual, residual)

    def reset(self) -> None:
        """Forget the correction carried from frame to frame."""
        # Per arm: the hand's translation in the pelvis frame (m) and the elbow's swivel (rad).
        self.state = np.zeros((2, 4))
        self._seen = False

    def __call__(self, surface: BodySurface, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray,
                 source: SourceContacts, dt: float) -> set[int]:
        """Both arms at once, from the last frame's correction let go by ``release_s`` (the prior):
        damped Gauss-Newton on each hand's translation (3) and elbow swivel (1) against its hand's
        and forearm's residuals and the prior, all gaps measured in one batch per step. Starting
        from the last frame's solution, the correction follows the motion continuously; with
        nothing left to keep it decays to none."""
        joints = ARMS[0].joints + ARMS[1].joints
        pelvis = glob[0].copy()
        first, self._seen = not self._seen, True
        decay = math.exp(-max(dt, 0.0) / self.release_s)
        prior = self.state * decay
        prior[:, :3] = prior[:, :3] @ pelvis.T  # to world axes
        if not prior.any():
            gaps = measure(surface, glob, pos, _ALL, self._reach, self.settings.tau)
            if not np.any(np.abs(self.residuals(gaps, source)) > 1e-5):
                self.state[:] = 0.0
                return set()
        saved = (glob[joints].copy(), loc[joints].copy(), pos[joints].copy())
        wrist0 = [pos[arm.wrist].copy() for arm in ARMS]
        last = self.state.copy()
        last[:, :3] = last[:, :3] @ pelvis.T
        # The first frame after a reset has no motion to follow: no limit.
        limit = np.array([MAX_HAND_SPEED, MAX_SWIVEL_SPEED]) * (np.inf if first else max(dt, 1e-3))
        state = self._limited(prior, last, limit)
        if state.any():
            self._apply(glob, loc, pos, saved, joints, wrist0, state)
        previous = np.zeros((2, 4))
        for _ in range(_ITERATIONS):
            gaps = measure(surface, glob, pos, _ALL, self._reach, self.settings.tau)
            res = self.residuals(gaps, source)
            active = np.abs(res) > 1e-5
            new = state.copy()
            for a, arm in enumerate(ARMS):
                mine = active & ((gaps.probe == arm.hand) | (gaps.probe == arm.forearm))
                step = self._step(pos, arm, gaps, res, mine, state[a] - prior[a])
                # A step turning back on the last one bounces between goals (out of the belly into
                # the thigh and back): half of it lands between them.
                if float(step[:3] @ previous[a, :3]) < 0.0:
                    step *= 0.5
                previous[a] = step
                new[a] += step
                move = float(np.sqrt(new[a, :3] @ new[a, :3]))
                if move > MAX_HAND_MOVE:
                    new[a, :3] *= MAX_HAND_MOVE / move
                new[a, 3] = min(max(new[a, 3], -MAX_SWIVEL), MAX_SWIVEL)
            # The rate limit, about the last frame's correction: the arm follows a jump smoothly.
            limited = self._limited(new, last, limit)
            step = np.abs(limited - state)
            if step.max() < 1e-6:
                break
            state = limited
            self._apply(glob, loc, pos, saved, joints, wrist0, state)
            # From the last frame's solution one step is usually enough; a large one is checked,
            # unless the rate limit held it back (another step could not go further this frame).
            held = np.abs(limited - new).max(1) > 1e-9
            settled = (step[:, :3].max(1) < SETTLED_STEP) & (step[:, 3] < SETTLED_SWIVEL)
            if np.all(held | settled):
                break
        # A correction let go down to a tenth of a millimetre is gone (not followed forever).
        gone = [a for a in range(2) if state[a].any() and np.abs(state[a, :3]).max() < 1e-4 and abs(state[a, 3]) < 1e-3
                and not np.any(np.abs(res[(gaps.probe == ARMS[a].hand) | (gaps.probe == ARMS[a].forearm)]) > 1e-5)]
        if gone:
            state[gone] = 0.0
            self._apply(glob, loc, pos, saved, joints, wrist0, state)
        self.state = state.copy()
        self.state[:, :3] = state[:, :3] @ pelvis  # back to the pelvis frame
        changed: set[int] = set()
        for a, arm in enumerate(ARMS):
            if state[a].any():
                changed.update(arm.joints)
        return changed

    @staticmethod
    def _limited(state: np.ndarray, last: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """``state`` moved back toward ``last`` until each arm's hand translation changed by at most
        limit[0] and its swivel by at most limit[1]."""
        out = state.copy()
        for a in range(len(state)):
            change = state[a, :3] - last[a, :3]
            size = float(np.sqrt(change @ change))
            if size > limit[0]:
                out[a, :3] = last[a, :3] + change * (limit[0] / size)
            out[a, 3] = min(max(state[a, 3], last[a, 3] - limit[1]), last[a, 3] + limit[1])
        return out

    def _apply(self, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray, saved: tuple, joints: list[int],
               wrist0: list[np.ndarray], state: np.ndarray) -> None:
        """The arms as the retargeter posed them, then each moved by its state."""
        glob[joints], loc[joints], pos[joints] = saved
        for a, arm in enumerate(ARMS):
            if state[a].any():
                self._pose(glob, loc, pos, arm, wrist0[a] + state[a, :3], state[a, 3])

    @staticmethod
    def _step(pos: np.ndarray, arm: _Arm, gaps: Gaps, res: np.ndarray, mine: np.ndarray, off_prior: np.ndarray
              ) -> np.ndarray:
        """One Gauss-Newton step (hand translation, swivel) of an arm from its rows and the prior
        (off_prior: how far the arm's state is from it), the step bounded."""
        direction, point, probe = gaps.direction[mine], gaps.point[mine], gaps.probe[mine]
        jac = np.zeros((len(direction), 4))
        jac[:, :3] = direction
        fore = probe == arm.forearm
        if fore.any():
            # A forearm point a fraction t from elbow to wrist moves about t times the hand's
            # move; the swivel turns it about the shoulder-wrist line.
            elbow, wrist, shoulder = pos[arm.elbow], pos[arm.wrist], pos[arm.shoulder]
            span = wrist - elbow
            t = np.clip((point[fore] - elbow) @ span / max(float(span @ span), 1e-12), 0.0, 1.0)
            axis = wrist - shoulder
            axis /= max(float(np.sqrt(axis @ axis)), 1e-9)
            jac[fore, :3] *= t[:, None]
            jac[fore, 3] = np.einsum("ki,ki->k", direction[fore], np.cross(axis, point[fore] - shoulder))
        step = np.linalg.solve(jac.T @ jac + _PRIOR, jac.T @ res[mine] - _PRIOR @ off_prior)
        move = float(np.sqrt(step[:3] @ step[:3]))
        if move > MAX_STEP:
            step[:3] *= MAX_STEP / move
        step[3] = min(max(step[3], -MAX_SWIVEL_STEP), MAX_SWIVEL_STEP)
        return step

    # -------------------------------------------------------------------------------- posing

    def _pose(self, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray, arm: _Arm, target: np.ndarray,
              swivel: float) -> None:
        """The arm with its wrist at ``target`` (two-bone IK; short of it, the collar turns toward
        it, in proportion to the miss, at most max_collar, and the IK runs again) and its elbow
        turned by ``swivel`` about the shoulder-wrist line. The hand keeps its world orientation.
        On plain floats (live/core/vec3.py), like the IK."""
        hand = glob[arm.wrist].tolist()
        g_collar, g_upper, g_lower = (glob[j].tolist() for j in (arm.collar, arm.shoulder, arm.elbow))
        collar, shoulder, elbow, wrist = (pos[j].tolist() for j in (arm.collar, arm.shoulder, arm.elbow, arm.wrist))
        goal = target.tolist()
        off_elbow, off_wrist = arm.offsets

        def reach(g_upper, g_lower, shoulder, elbow, wrist):
            upper, lower = limb_ik(shoulder, elbow, wrist, goal, v3.mv(g_upper, arm.hinge_axis))
            g_upper, g_lower = v3.mm(upper, g_upper), v3.mm(lower, g_lower)
            elbow = v3.add(shoulder, v3.mv(g_upper, off_elbow))
            return g_upper, g_lower, elbow, v3.add(elbow, v3.mv(g_lower, off_wrist))

        g_upper, g_lower, elbow, wrist = reach(g_upper, g_lower, shoulder, elbow, wrist)
        miss = v3.sub(goal, wrist)
        bone = v3.sub(shoulder, collar)
        length2 = v3.dot(bone, bone)
        across = v3.sub(miss, v3.scale(bone, v3.dot(miss, bone) / max(length2, 1e-12)))
        size = v3.norm(across)
        turned = size > 1e-5 and length2 > 1e-12
        if turned:
            turn = v3.axis_angle(v3.unit(v3.cross(bone, across)), min(size / math.sqrt(length2), self.max_collar))
            g_collar, g_upper, g_lower = v3.mm(turn, g_collar), v3.mm(turn, g_upper), v3.mm(turn, g_lower)
            shoulder, elbow, wrist = (v3.add(collar, v3.mv(turn, v3.sub(p, collar))) for p in (shoulder, elbow, wrist))
            g_upper, g_lower, elbow, wrist = reach(g_upper, g_lower, shoulder, elbow, wrist)
        if swivel != 0.0:
            turn = v3.axis_angle(v3.unit(v3.sub(wrist, shoulder)), swivel)
            g_upper, g_lower = v3.mm(turn, g_upper), v3.mm(turn, g_lower)
            elbow = v3.add(shoulder, v3.mv(turn, v3.sub(elbow, shoulder)))
        if turned:
            glob[arm.collar] = g_collar
            loc[arm.collar] = v3.mtm(glob[PARENTS[arm.collar]].tolist(), g_collar)
        glob[arm.shoulder], glob[arm.elbow] = g_upper, g_lower
        pos[arm.shoulder], pos[arm.elbow], pos[arm.wrist] = shoulder, elbow, wrist
        loc[arm.shoulder] = v3.mtm(g_collar, g_upper)
        loc[arm.elbow] = v3.mtm(g_upper, g_lower)
        loc[arm.wrist] = v3.mtm(g_lower, hand)
