"""Self-contacts kept on the avatar and hands and forearms kept out of its body, one frame at a time.

After any retargeter (rotation copy or the network), on the avatar's own surface
(live/retarget/contacts_surface.py), both arms solved together:

1. **Bounds.** Every region near a hand or forearm (the other hand and arm, head, torso, legs)
   bounds its gap: where the performer is in contact with it (weight w from
   live/retarget/contacts_self.py), the performer's gap, at least ``margin``, from both sides;
   elsewhere only from below, min(the performer's gap, ``clearance``) and at least ``margin`` (no
   sinking in, no touching where the performer does not; a hand in contact somewhere keeps only
   the margin from the rest). Forearms keep the margin. A row's residual (along the region's
   outward direction) is how far its gap is outside its bounds.
2. **Unknowns.** Per arm, a rotation of the whole arm about the shoulder (3) and the elbow's
   flexion about its hinge (1); the hand keeps its world orientation and moves with the wrist,
   so a contact lands where the rotation copy put the hand in the touched part's frame, moved
   onto the avatar's skin at the performer's gap. The two arms are one system: a row between a
   hand and the other hand or arm moves with both arms (a hand pushed out of a belly takes the
   forearm it holds along, rather than each arm closing half the gap and the pair coming apart).
   The two rows between the hands (the left hand's gap to the right hand and back) are given
   one direction, opposite for the two: inside each other, each hand's distance field points
   to its own nearest skin and the two could cancel.
3. **Least displacement.** Damped Gauss-Newton on the residuals (pushing out weighs
   PUSH_WEIGHT times pulling in) plus a small cost on how far the elbows and wrists move from
   the retargeter's pose (the joint error a viewer and MPJPE see), so the arm moves only as far
   as the bounds need, by the joints that move least. A row just above its lower bound is a
   wall the step may not cross (added to the step's system only when it would). The elbow's
   flexion stays between the input's and anatomical limits (never past straight).
4. **In time.** Each frame starts where the last one ended; the prior the steps are damped
   toward is that correction let go with ``release_s``. An arm holding no contact starts from
   that prior itself where it sinks nothing (settings ``let_go``: exact skeletons); elsewhere the
   arms follow it out at the damped steps' pace, 2-5 % of the correction a frame at 30 fps. Up to
   _ITERATIONS steps (_DEEP_ITERATIONS while a hand or forearm is still deep inside). The
   correction's change is rate-limited: its elbows and wrists move at most MAX_HAND_SPEED plus
   INPUT_SHARE of the retargeter's own wrist speed, so goals that jump while the hand is still
   (a contact starting, a hand slipping between thigh and belly) are followed smoothly, and a
   hand that strikes or claps fast is still pushed out. An arm that the carried correction holds
   deep inside the body, deeper than the retargeter's own pose would be, starts again from that
   pose. A frame with nothing near is left exactly as the retargeter made it.
5. **Push-out.** A hand or forearm still more than PUSH_DEPTH inside after the steps (a strike,
   a pose entering the body faster than the rate-limited steps follow) is pushed out to the skin
   by least-displacement steps that the rate limit and the prior do not hold back, the other
   rows kept as walls, an elbow or wrist moved up to PUSH_MAX_MOVE; the next frame starts from
   there.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from live.core import vec3 as v3
from live.core.geometry import segment_distances
from live.core.rotations import skew
from live.core.skeleton import PARENTS
from live.retarget.analytic import LIMBS
from live.retarget.contacts_self import ContactSettings, SourceContacts
from live.retarget.contacts_surface import ALL_PROBES, BAND, PROBES, REGIONS, BodySurface, Gaps, measure

#: Gauss-Newton steps per frame at most (each measures the gaps once), and at most when a hand
#: or forearm is still more than DEEP (m) inside the body (a strike, the first frame).
_ITERATIONS = 1
_DEEP_ITERATIONS = 2
DEEP = 0.004
#: Weight of the elbows' and wrists' displacement from the retargeter's pose against the
#: residuals (m^2 per m^2): small, so the goals win and the displacement only picks, of the
#: poses that meet them, the one nearest the retargeter's.
DISPLACEMENT_WEIGHT = 0.05
#: Weight of the prior (the last frame's correction, let go) per unknown (per rad^2): with nothing
#: to keep, the correction follows it out; and a step's largest rotation of arm and elbow (rad).
_PRIOR = 0.005
MAX_STEP = 0.25
#: Levenberg-Marquardt damping of a step per unknown (per rad^2): deep inside a body the surface's
#: direction changes from one step to the next, and undamped steps swung the arms back and forth
#: between frames (with two steps at most while deep, on the tuning takes: penetration 7.2 -> 6.0 mm
#: mean, acceleration 2.3 -> 1.8 mm/frame², the stage 2.5 -> 2.0 ms p95).
STEP_DAMPING = 0.05
#: A step whose elbow and wrist move less than this (m) ends the frame's iterations.
SETTLED_STEP = 0.003
#: The most an elbow or a wrist is moved from the retargeter's pose (m): where the bounds conflict
#: (forearms folded across a belly 10 cm deeper than the performer's, hands holding each other)
#: the steps would otherwise wander off frame after frame.
MAX_MOVE = 0.25
#: The elbow's flexion bounds (rad, 0 = straight): never past straight, at most this bent.
MIN_BEND = 0.05
MAX_BEND = 2.6
#: Weight of a forearm's contacts against a hand's: none. Viewers notice them much less, and a
#: forearm held to a hip fights the hand's own goals where bodies differ most; forearms are only
#: kept out of the body.
FOREARM_CONTACT_WEIGHT = 0.0
#: How fast the correction may move an elbow or a wrist: MAX_HAND_SPEED (m/s) plus INPUT_SHARE of
#: the retargeter's own wrist speed. A goal that jumps while the hand is still is followed
#: smoothly; a hand that strikes into the body is pushed out about as fast as it comes in (all
#: of the wrist's speed: a third less penetration on fast takes, a quarter more acceleration).
MAX_HAND_SPEED = 0.8
INPUT_SHARE = 0.5
#: The most gap (m) of a row with no contact: none.
FAR_GOAL = 1e3
#: How far (m) a probe set holding a contact looks for what it holds.
HOLD_REACH = 0.15
#: Rows within this (m) above their least gap are walls the step may not cross.
NEAR = 0.01
#: Weight of the rows that push out of the body against those that pull toward a contact.
PUSH_WEIGHT = 3.0
#: An arm whose carried correction holds it more than RESTART_DEPTH (m) inside the body, and
#: RESTART_GAIN (m) deeper than the retargeter's own pose would be, starts again from that pose:
#: arms swinging out of a heavy belly otherwise drag the correction through it (on the tuning
#: takes penetration 5.1 -> 4.6 mm mean, 63 -> 60 max, MPJPE and acceleration a little lower).
RESTART_DEPTH = 0.02
RESTART_GAIN = 0.005
#: A hand or forearm still more than PUSH_DEPTH (m) inside after the steps is pushed out to
#: PUSH_TO along the surface's normal, by at most PUSH_STEPS least-displacement steps that
#: neither the rate limit nor the prior holds back: a strike or a pose entering a body sinks
#: faster than the damped, rate-limited steps follow (a salsa's hand 13 mm inside a head after
#: two steps from 63, the first frame of a strike 41 mm inside a belly with the rate limit).
PUSH_DEPTH = 0.004
PUSH_STEPS = 2
#: Where a push-out takes a deep row (m: the skin, or its least gap if lower; the steps of the
#: next frames take it on to the margin, a smaller jump), and how far it looks for walls (m).
PUSH_TO = 0.0
PUSH_REACH = 0.1
#: Weight of the elbows' and wrists' move against the deep rows in a push-out step: it picks the
#: least move that frees them.
PUSH_DISPLACEMENT = 0.01
#: The most a push-out may move an elbow or a wrist from the retargeter's pose (m): more than
#: MAX_MOVE. An arm the steps have carried to MAX_MOVE along a heavy belly (hands clasped in
#: front of it, 10 cm inside on the retargeter's pose) had every push scaled back into the body
#: (a salsa's forearm 40-58 mm inside for three frames, the push-out predicting it out).
PUSH_MAX_MOVE = 0.4


class _Arm:
    """The joints and probe sets of one arm."""

    def __init__(self, side: str, index: int):
        limb = LIMBS[2] if side == "left" else LIMBS[3]
        self.side, self.index = side, index
        self.shoulder, self.elbow, self.wrist = (int(j) for j in limb[:3])
        self.hinge_axis = tuple(float(x) for x in limb[3])
        self.hand = next(i for i, p in enumerate(PROBES) if p.name == f"{side}_hand")
        self.forearm = next(i for i, p in enumerate(PROBES) if p.name == f"{side}_forearm")
        self.joints = [self.shoulder, self.elbow, self.wrist]
        self.hand_region = REGIONS.index(f"{side}_hand")
        self.arm_region = REGIONS.index(f"{side}_arm")


ARMS = (_Arm("left", 0), _Arm("right", 1))
#: Per probe set: its arm and whether it is a hand. Per region: the arm it belongs to (-1: none)
#: and whether it is that arm's hand.
_PROBE_ARM = np.array([0 if p.side == "left" else 1 for p in PROBES])
_PROBE_HAND = np.array([p.kind == "hand" for p in PROBES])
_REGION_ARM = np.array([0 if r.startswith("left_") and r[5:] in ("hand", "arm") else
                        1 if r.startswith("right_") and r[6:] in ("hand", "arm") else -1 for r in REGIONS])
_REGION_HAND = np.array([r.endswith("_hand") for r in REGIONS])

#: The two rows between the hands, (probe set, region) each: the left hand's gap to the right
#: hand and the right hand's to the left. (A hand and the other arm are no such pair: the arm's
#: region holds the upper arm too, and its two rows may measure different contacts. Made one way
#: as well, on the tuning takes a curled-in take's hands met where the performer's did not:
#: precision 92.6 -> 89.6 %.)
HAND_ROWS = tuple((int(np.flatnonzero(_PROBE_HAND & (_PROBE_ARM == a))[0]), REGIONS.index(f"{other}_hand"))
                  for a, other in ((0, "right"), (1, "left")))
_ARM_PROBES = (np.flatnonzero(_PROBE_ARM == 0), np.flatnonzero(_PROBE_ARM == 1))


class _Posed:
    """One arm of one frame: the retargeter's pose (``base``) and a correction applied to it."""

    def __init__(self, glob: np.ndarray, pos: np.ndarray, arm: _Arm):
        self.arm = arm
        self.collar = glob[PARENTS[arm.shoulder]].tolist()
        self.g_upper, self.g_lower, self.g_hand = (glob[j].tolist() for j in arm.joints)
        self.s, self.e0, self.w0 = (pos[j].tolist() for j in arm.joints)
        ab, cb = v3.sub(self.e0, self.s), v3.sub(self.w0, self.e0)
        hint = v3.mv(self.g_upper, arm.hinge_axis)
        hint = v3.sub(hint, v3.scale(ab, v3.dot(hint, ab) / max(v3.dot(ab, ab), v3.EPS)))
        # Turning the forearm about n0 by a positive angle straightens the elbow (as limb_ik's).
        self.n0 = v3.scale(v3.unit(hint), -1.0)
        self.bend0 = math.atan2(v3.dot(v3.cross(cb, ab), self.n0), v3.dot(ab, cb))
        self.fore0 = cb
        self.upper0 = ab
        self._last: tuple = (None, None)  # the last state posed and its pose

    def pose(self, x: np.ndarray) -> tuple:
        """(upper arm rotation R, flexion rotation F, elbow, wrist, flex axis) of state x (4,):
        x[:3] the whole arm's rotation vector (world), x[3] the elbow's straightening (rad)."""
        key = tuple(x.tolist())  # plain floats: numpy scalars are slower in this arithmetic
        if key == self._last[0]:  # a step's pose right after the same state was applied
            return self._last[1]
        x0, x1, x2, x3 = key
        angle = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        r = v3.axis_angle((x0 / angle, x1 / angle, x2 / angle), angle) if angle > 1e-12 else v3.IDENTITY
        n = v3.mv(r, self.n0)
        f = v3.mm(v3.axis_angle(n, x3), r) if x3 != 0.0 else r
        elbow = v3.add(self.s, v3.mv(r, self.upper0))
        posed = (r, f, elbow, v3.add(elbow, v3.mv(f, self.fore0)), n)
        self._last = (key, posed)
        return posed


class ContactKeeper:
    """Keeps the performer's contacts on the avatar and its hands and forearms out of its body.

    offsets: the avatar's rest offsets (22, 3); settings: as the detector's. ``__call__`` changes
    one frame's global and local rotations and joints in place and returns the joints it
    rotated (a set, empty when nothing was near)."""

    def __init__(self, offsets: np.ndarray, settings: ContactSettings = ContactSettings()):
        self.offsets = np.asarray(offsets, np.float64)
        self.settings = settings
        self.release_s = settings.blend_s
        self.reset()
        s = settings
        # Per probe set: how far to look, the most a floor asks, the weight of its contacts.
        self._reach = np.where(_PROBE_HAND, max(s.reach, s.clearance), s.reach) + s.margin
        self._floor_cap = np.where(_PROBE_HAND, max(s.clearance, s.margin), s.margin)
        self._contact_weight = np.where(_PROBE_HAND, 1.0, FOREARM_CONTACT_WEIGHT)
        #: The probe sets whose performer contacts count (the others' bounds do not depend on them).
        self.held_probes = np.flatnonzero(self._contact_weight > 0.0)

    def bounds(self, gaps: Gaps, source: SourceContacts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per row: the least gap (m) it may have, the most (inf but for a kept contact) and the
        weight of its contact. Where the performer is in contact: its gap, at least the margin
        (least and most). Elsewhere a floor: not closer than
        min(performer's gap, clearance), never within margin; a hand in contact somewhere only
        keeps the margin from the rest (between a heavy avatar's thigh and belly there may be no
        room for more). The two blend by the contact's weight."""
        s = self.settings
        src_gap = source.gap[gaps.probe, gaps.region]
        w = source.weight[gaps.probe, gaps.region] * self._contact_weight[gaps.probe]
        busy = (source.weight * self._contact_weight[:, None]).max(1)[gaps.probe]
        cap = self._floor_cap[gaps.probe] * (1.0 - busy) + s.margin * busy
        goal = np.full_like(src_gap, s.margin) if s.touch else np.maximum(src_gap, s.margin)
        floor = _floor(src_gap, cap, s.margin)
        return w * goal + (1.0 - w) * floor, np.where(w > 0.0, goal, FAR_GOAL), w

    def _clear(self, gaps: Gaps, source: SourceContacts) -> np.ndarray:
        """Per row: the floor of a probe set holding nothing, min(the performer's gap, its cap), at
        least the margin."""
        return _floor(source.gap[gaps.probe, gaps.region], self._floor_cap[gaps.probe], self.settings.margin)

    def residuals(self, gaps: Gaps, source: SourceContacts) -> np.ndarray:
        """Each row's residual (m, along its direction, positive: out): up to its least gap, or
        back (by the contact's weight) to its most."""
        lower, upper, w = self.bounds(gaps, source)
        return np.where(gaps.gap < lower, lower - gaps.gap, np.where(gaps.gap > upper, w * (upper - gaps.gap), 0.0))

    def reset(self) -> None:
        """Forget the correction carried from frame to frame."""
        # Per arm: the arm's rotation vector in the pelvis frame (3) and the elbow's straightening.
        self.state = np.zeros((2, 4))
        self._seen = False
        self._wrists = np.zeros((2, 3))

    def __call__(self, surface: BodySurface, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray,
                 source: SourceContacts, dt: float) -> set[int]:
        """Both arms at once, from the last frame's correction let go by ``release_s``."""
        pelvis = glob[0].copy()
        first, self._seen = not self._seen, True
        decay = math.exp(-max(dt, 0.0) / self.release_s)
        prior = self.state * decay
        prior[:, :3] = prior[:, :3] @ pelvis.T  # to world axes
        # The retargeter's wrists in the pelvis frame: how fast they move bounds the correction's change.
        wrists = pos[[ARMS[0].wrist, ARMS[1].wrist]] @ pelvis
        moved = np.full(2, np.inf) if first else np.sqrt(((wrists - self._wrists) ** 2).sum(1))
        self._wrists = wrists
        # A probe set holding a contact looks far: a hand pushed away from what it holds still
        # sees it and is pulled back (unmeasured, the contact would simply be let go).
        holding = (source.weight * self._contact_weight[:, None]).max(1) > 0.0
        reach = np.where(holding, HOLD_REACH, self._reach)
        band = np.where(holding, HOLD_REACH, BAND)
        gaps = None
        if not prior.any():
            gaps = self._measure(surface, glob, pos, reach, band)
            if not np.any(np.abs(self.residuals(gaps, source)) > 1e-5):
                self.state[:] = 0.0
                return set()
        arms = [_Posed(glob, pos, arm) for arm in ARMS]
        last = self.state.copy()
        last[:, :3] = last[:, :3] @ pelvis.T
        # The correction changes by at most MAX_HAND_SPEED plus a share of the retargeter's own
        # wrist speed (the first frame after a reset has no motion to follow: no limit).
        limit = MAX_HAND_SPEED * max(dt, 1e-3) + INPUT_SHARE * moved
        # Warm start from where the last frame ended (starting from the let-go prior instead, a
        # hand held at a wall bounces: let in a little, pushed out again, every frame), or, for an
        # arm holding nothing, from the let-go prior where that sinks nothing.
        state = last.copy()
        if state.any():
            gaps = self._let_go(surface, glob, loc, pos, arms, state, prior, source, holding, reach, band) \
                if self.settings.let_go else None
            if gaps is None:
                self._apply(glob, loc, pos, arms, state)
                gaps = self._measure(surface, glob, pos, reach, band)
            if RESTART_DEPTH > 0:
                gaps = self._drop_worse(surface, glob, loc, pos, arms, state, last, gaps, reach, band)
        res, seen = np.zeros(0), Gaps.empty()
        for iteration in range(_DEEP_ITERATIONS):
            if gaps is None:
                gaps = self._measure(surface, glob, pos, reach, band)
            lower, upper, w = self.bounds(gaps, source)
            res = np.where(gaps.gap < lower, lower - gaps.gap, np.where(gaps.gap > upper, w * (upper - gaps.gap), 0.0))
            seen = gaps
            if not np.any(np.abs(res) > 1e-5) and not state.any():
                break
            new = state + self._step(arms, state, prior, gaps, res, lower)
            _clamp_bend(arms, new)
            limited = self._limited(arms, new, last, limit)
            far = self._moves(arms, limited)
            limited *= np.minimum(1.0, MAX_MOVE / np.maximum(far, 1e-12))[:, None]
            step = self._moves(arms, limited - state)
            held = self._moves(arms, new - limited) > 1e-6  # the rate limit held it back
            state = limited
            self._apply(glob, loc, pos, arms, state)
            # Another step when this one moved far and the rate limit did not hold it (one more
            # could not go further this frame); past _ITERATIONS only while still deep inside.
            if np.all(held | (step < SETTLED_STEP)) or \
                    (iteration + 1 >= _ITERATIONS and not np.any(gaps.gap < -DEEP)):
                break
            gaps = None
        if PUSH_STEPS and len(seen.gap) and float(seen.gap.min()) < -PUSH_DEPTH:
            self._push_out(surface, glob, loc, pos, arms, state, source, reach, band)
        # A correction let go down to a tenth of a millimetre is gone (not followed forever).
        gone = [a for a in range(2) if state[a].any() and self._moves(arms, state)[a] < 1e-4
                and not np.any((_PROBE_ARM[seen.probe] == a) & (np.abs(res) > 1e-5))]
        if gone:
            state[gone] = 0.0
            self._apply(glob, loc, pos, arms, state)
        self.state = state.copy()
        self.state[:, :3] = state[:, :3] @ pelvis  # back to the pelvis frame
        changed: set[int] = set()
        for a, arm in enumerate(ARMS):
            if state[a].any():
                changed.update(arm.joints)
        return changed

    def _measure(self, surface: BodySurface, glob: np.ndarray, pos: np.ndarray, reach: np.ndarray,
                 band: np.ndarray) -> Gaps:
        """Every probe set's gaps in this pose, the rows between the hands made one way."""
        return _hands_one_way(measure(surface, glob, pos, ALL_PROBES, reach, self.settings.tau, band))

    def _let_go(self, surface: BodySurface, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray,
                arms: list[_Posed], state: np.ndarray, prior: np.ndarray, source: SourceContacts,
                holding: np.ndarray, reach: np.ndarray, band: np.ndarray) -> Gaps | None:
        """An arm that holds no contact starts from its correction let go (``prior``) rather than
        where the last frame ended, when that puts none of its hand's and forearm's rows below
        their least gap (``state`` changed in place). The steps alone let a correction go at their
        damped pace, a few per cent a frame; a clapping hand stayed pushed aside between the claps.
        Where letting go would sink the arm or bring it too near, it keeps the last frame's
        correction (let in and pushed out again, a hand would bounce). Returns the gaps of the
        pose it leaves applied, or None when ``state`` is still to be applied and measured
        (nothing tried, or an arm kept)."""
        free = [a for a in range(2) if state[a].any() and not holding[_ARM_PROBES[a]].any()
                and not np.array_equal(state[a], prior[a])]
        if not free:
            return None
        trial = state.copy()
        trial[free] = prior[free]
        self._apply(glob, loc, pos, arms, trial)
        gaps = self._measure(surface, glob, pos, reach, band)
        lower = self.bounds(gaps, source)[0]
        below = gaps.gap < lower - 1e-5
        let_go = [a for a in free if not np.any(below & (_PROBE_ARM[gaps.probe] == a))]
        state[let_go] = trial[let_go]
        return gaps if len(let_go) == len(free) else None

    def _drop_worse(self, surface: BodySurface, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray,
                    arms: list[_Posed], state: np.ndarray, last: np.ndarray, gaps: Gaps, reach: np.ndarray,
                    band: np.ndarray) -> Gaps | None:
        """An arm whose carried correction holds it more than RESTART_DEPTH inside the body, deeper
        by RESTART_GAIN than the retargeter's own pose would be, starts again from that pose
        (``state`` and ``last`` changed in place; None: to be measured again). Arms that swing
        out of a belly otherwise drag the correction of the frames before through it."""
        dropped = False
        for a in range(2):
            if not state[a].any():
                continue
            mine = _PROBE_ARM[gaps.probe] == a
            deep = float(gaps.gap[mine].min()) if mine.any() else 0.0
            if deep > -RESTART_DEPTH:
                continue
            trial = state.copy()
            trial[a] = 0.0
            self._apply(glob, loc, pos, arms, trial)
            probes = _ARM_PROBES[a]
            base = measure(surface, glob, pos, probes, reach[probes], self.settings.tau, band[probes])
            if (float(base.gap.min()) if len(base.gap) else 0.0) > deep + RESTART_GAIN:
                state[a] = last[a] = 0.0
                dropped = True
            self._apply(glob, loc, pos, arms, state)
        return None if dropped else gaps

    def _push_out(self, surface: BodySurface, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray,
                  arms: list[_Posed], state: np.ndarray, source: SourceContacts, reach: np.ndarray,
                  band: np.ndarray) -> None:
        """Rows still more than PUSH_DEPTH inside pushed out to PUSH_TO (``state`` and the pose
        changed in place), the other rows kept from going deeper than they are; the elbow's
        bounds and MAX_MOVE still hold. The pushed state is the next frame's warm start, so a hand
        held out stays out rather than sinking and popping out frame after frame."""
        # Measured as far as a push may move a hand, so that what it could run into is a wall.
        reach, band = np.maximum(reach, PUSH_REACH), np.maximum(band, PUSH_REACH)
        for _ in range(PUSH_STEPS):
            gaps = self._measure(surface, glob, pos, reach, band)
            deep = gaps.gap < -PUSH_DEPTH
            if not deep.any():
                return
            lower, upper, w = self.bounds(gaps, source)
            # Walls: a push does not bring a hand nearer than its clearance to what the performer
            # does not touch (the looser floor of a hand holding something lets the steps settle
            # it there; a push is a jump of centimetres, and hands ended up held together).
            walls = np.where(w > 0.0, lower, np.maximum(lower, self._clear(gaps, source)))
            lower = np.where(deep, np.minimum(lower, PUSH_TO), walls)
            new = state + _push_step(self._rows_jacobian(arms, state, gaps), gaps.gap, lower, upper, deep,
                                     self._displacement(arms, state)[1])
            _clamp_bend(arms, new)
            new *= np.minimum(1.0, PUSH_MAX_MOVE / np.maximum(self._moves(arms, new), 1e-12))[:, None]
            state[:] = new
            self._apply(glob, loc, pos, arms, state)

    # ------------------------------------------------------------------------------ the solve

    @staticmethod
    def _levers(arms: list[_Posed], posed: list[tuple], arm_of: np.ndarray, hand: np.ndarray,
                points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For points (K, 3) on arms arm_of (K,) (hand: moving with the wrist; else on the arm:
        forearm or upper arm, whichever segment is nearer): the levers about the shoulder and
        about the elbow (zero for the upper arm) and the flex axes."""
        # Per arm: shoulder, elbow, wrist, flex axis (2, 4, 3); then per point.
        per_arm = np.array([[arms[a].s, posed[a][2], posed[a][3], posed[a][4]] for a in range(2)])[arm_of]
        s, e, w, n = per_arm[:, 0], per_arm[:, 1], per_arm[:, 2], per_arm[:, 3]
        p = np.where(hand[:, None], w, points)
        upper = segment_distances(p, s, e) < segment_distances(p, e, w)
        about_elbow = np.where(upper[:, None] & ~hand[:, None], 0.0, p - e)
        return p - s, about_elbow, n

    def _step(self, arms: list[_Posed], state: np.ndarray, prior: np.ndarray, gaps: Gaps, res: np.ndarray,
              lower: np.ndarray) -> np.ndarray:
        """One damped Gauss-Newton step (2, 4) of both arms: the rows' residuals, the elbows' and
        wrists' displacement from the retargeter's pose, the prior. A row near its least gap but
        not below it is a wall: added (held at its least gap) only when the step would cross it,
        so that the least displacement does not pull a hand back into what it was pushed out of."""
        rows = np.flatnonzero((res != 0.0) | (gaps.gap < lower + NEAR))
        jac = self._rows_jacobian(arms, state, gaps, rows)
        disp, jd = self._displacement(arms, state)
        lam = DISPLACEMENT_WEIGHT
        base_h = lam * (jd.T @ jd) + (_PRIOR + STEP_DAMPING) * np.eye(8)
        base_g = -lam * (jd.T @ disp) - _PRIOR * (state - prior).ravel()
        r = res[rows]
        gap, wall = gaps.gap[rows], lower[rows]
        use = r != 0.0
        step = np.zeros(8)
        for _ in range(3):
            weight = np.where(r > 0.0, PUSH_WEIGHT, 1.0) * use
            wjac = jac * weight[:, None]
            step = np.linalg.solve(wjac.T @ jac + base_h, wjac.T @ r + base_g)
            crossing = ~use & (gap + jac @ step < wall)
            if not crossing.any():
                break
            use |= crossing
            r = np.where(crossing, wall - gap, r)
        return _limit_step(step)

    def _rows_jacobian(self, arms: list[_Posed], state: np.ndarray, gaps: Gaps, rows: np.ndarray | None = None
                       ) -> np.ndarray:
        """(R, 8) how the gaps of rows (default all) grow with both arms' unknowns in state: a
        row's own probe set moves with its arm, and a touched hand or arm with the other arm."""
        posed = [p.pose(state[a]) for a, p in enumerate(arms)]
        rows = np.arange(len(gaps.gap)) if rows is None else rows
        direction, point = gaps.direction[rows], gaps.point[rows]
        jac = np.zeros((len(rows), 8))
        probe = gaps.probe[rows]
        own = _PROBE_ARM[probe]
        lu, le, n = self._levers(arms, posed, own, _PROBE_HAND[probe], point)
        _add_rows(jac, own, lu, le, n, direction, 1.0)
        other = _REGION_ARM[gaps.region[rows]]
        theirs = np.flatnonzero(other >= 0)
        if len(theirs):
            # The touched point of the other arm moves with it: the gap closes by both moves.
            touched = point[theirs] - gaps.gap[rows][theirs, None] * direction[theirs]
            lu, le, n = self._levers(arms, posed, other[theirs], _REGION_HAND[gaps.region[rows][theirs]], touched)
            sub = np.zeros((len(theirs), 8))
            _add_rows(sub, other[theirs], lu, le, n, direction[theirs], -1.0)
            jac[theirs] += sub
        return jac

    @staticmethod
    def _displacement(arms: list[_Posed], state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The elbows' and wrists' displacement (12,) from the retargeter's pose in state, and its
        Jacobian (12, 8) in the unknowns."""
        posed = [p.pose(state[a]) for a, p in enumerate(arms)]
        disp, jd = np.zeros(12), np.zeros((12, 8))
        levers = skew(np.array([v3.sub(joint, p.s) for p, q in zip(arms, posed) for joint in q[2:4]]))
        for a, (p, (_, _, elbow, wrist, n_a)) in enumerate(zip(arms, posed)):
            disp[6 * a:6 * a + 3] = v3.sub(elbow, p.e0)
            disp[6 * a + 3:6 * a + 6] = v3.sub(wrist, p.w0)
            jd[6 * a:6 * a + 3, 4 * a:4 * a + 3] = -levers[2 * a]
            jd[6 * a + 3:6 * a + 6, 4 * a:4 * a + 3] = -levers[2 * a + 1]
            jd[6 * a + 3:6 * a + 6, 4 * a + 3] = v3.cross(n_a, v3.sub(wrist, elbow))
        return disp, jd

    @staticmethod
    def _moves(arms: list[_Posed], change: np.ndarray) -> np.ndarray:
        """(2,) how far a change of state (2, 4) moves each arm's elbow or wrist, at most (m, to
        first order about the retargeter's pose)."""
        out = np.zeros(2)
        for a, (p, row) in enumerate(zip(arms, change.tolist())):
            rot = row[:3]
            elbow = v3.cross(rot, p.upper0)
            wrist = v3.add(v3.add(elbow, v3.cross(rot, p.fore0)), v3.scale(v3.cross(p.n0, p.fore0), row[3]))
            out[a] = math.sqrt(max(v3.dot(elbow, elbow), v3.dot(wrist, wrist)))
        return out

    def _limited(self, arms: list[_Posed], state: np.ndarray, last: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """``state`` moved back toward ``last`` until no elbow or wrist of arm a moved by more
        than ``limit[a]`` (m)."""
        out = state.copy()
        moves = self._moves(arms, state - last)
        for a in range(2):
            if moves[a] > limit[a]:
                out[a] = last[a] + (state[a] - last[a]) * (limit[a] / moves[a])
        return out

    # -------------------------------------------------------------------------------- posing

    @staticmethod
    def _apply(glob: np.ndarray, loc: np.ndarray, pos: np.ndarray, arms: list[_Posed], state: np.ndarray) -> None:
        """The arms as the retargeter posed them, each turned by its state; the hand keeps its
        world orientation."""
        for a, p in enumerate(arms):
            arm = p.arm
            if not state[a].any():
                glob[arm.shoulder], glob[arm.elbow] = p.g_upper, p.g_lower
                pos[arm.elbow], pos[arm.wrist] = p.e0, p.w0
                loc[arm.shoulder] = v3.mtm(p.collar, p.g_upper)
                loc[arm.elbow] = v3.mtm(p.g_upper, p.g_lower)
                loc[arm.wrist] = v3.mtm(p.g_lower, p.g_hand)
                continue
            r, f, elbow, wrist, _ = p.pose(state[a])
            g_upper, g_lower = v3.mm(r, p.g_upper), v3.mm(f, p.g_lower)
            glob[arm.shoulder], glob[arm.elbow] = g_upper, g_lower
            pos[arm.elbow], pos[arm.wrist] = elbow, wrist
            loc[arm.shoulder] = v3.mtm(p.collar, g_upper)
            loc[arm.elbow] = v3.mtm(g_upper, g_lower)
            loc[arm.wrist] = v3.mtm(g_lower, p.g_hand)


def _hands_one_way(gaps: Gaps) -> Gaps:
    """Gaps whose two rows between the hands (HAND_ROWS), measured from either side, point one
    way: the difference of their directions, opposite for the two. Inside each other, each
    hand's distance field points to its own nearest skin, and the two directions can ask the same
    arm to go two ways at once (hands clasped in front of a heavy belly stayed 10-20 mm inside
    each other, their rows cancelling)."""
    (probe_a, region_a), (probe_b, region_b) = HAND_ROWS
    row_a = np.flatnonzero((gaps.probe == probe_a) & (gaps.region == region_a))
    row_b = np.flatnonzero((gaps.probe == probe_b) & (gaps.region == region_b))
    if not (len(row_a) and len(row_b)):
        return gaps
    i, j = row_a[0], row_b[0]
    # A row's direction is out of its region: where its own hand should go.
    way = gaps.direction[i] - gaps.direction[j]
    size = float(np.sqrt(way @ way))
    if size < 1e-3:  # the two already ask the same arm both ways: apart along their points
        way = gaps.point[i] - gaps.point[j]
        size = float(np.sqrt(way @ way))
        if size < 1e-6:
            return gaps
    direction = gaps.direction.copy()
    direction[i], direction[j] = way / size, -way / size
    return replace(gaps, direction=direction)


def _floor(src_gap: np.ndarray, cap: np.ndarray, margin: float) -> np.ndarray:
    """A row's floor: min(the performer's gap, its cap), never within the margin."""
    return np.clip(src_gap, margin, np.maximum(cap, margin))


def _limit_step(step: np.ndarray) -> np.ndarray:
    """A solve's step (8,) as (2, 4), each arm's rotation at most MAX_STEP (rad) and its elbow's
    change at most MAX_STEP."""
    step = step.reshape(2, 4)
    size = np.sqrt((step[:, :3] ** 2).sum(1))
    step[:, :3] *= np.minimum(1.0, MAX_STEP / np.maximum(size, 1e-12))[:, None]
    step[:, 3] = np.clip(step[:, 3], -MAX_STEP, MAX_STEP)
    return step


def _clamp_bend(arms: list[_Posed], state: np.ndarray) -> None:
    """The elbows' straightening in state (2, 4, in place) kept between straight and MAX_BEND
    (neither past straight nor folded further)."""
    for a, p in enumerate(arms):
        lo, hi = p.bend0 - max(p.bend0, MAX_BEND), p.bend0 - min(p.bend0, MIN_BEND)
        state[a, 3] = min(max(state[a, 3], lo), hi)


def _push_step(jac: np.ndarray, gap: np.ndarray, lower: np.ndarray, upper: np.ndarray, deep: np.ndarray,
               jd: np.ndarray) -> np.ndarray:
    """A step (2, 4) taking the deep rows (mask) to their least gap with the least move of the
    elbows and wrists (jd: their Jacobian (12, 8)). The other rows are walls, added only when the
    step would cross them: none goes deeper than min(gap, least gap), and a kept contact no
    farther than max(gap, most gap) (a hand leaving a belly does not let go of what it holds).
    jac (R, 8): the rows' Jacobian; gap, lower, upper (R,)."""
    use = deep.copy()
    floor = np.where(deep, lower, np.minimum(gap, lower))
    ceiling = np.maximum(gap, upper)
    target = floor.copy()
    base = PUSH_DISPLACEMENT * (jd.T @ jd) + 1e-6 * np.eye(8)
    step = np.zeros(8)
    for _ in range(3):
        j = jac[use]
        step = np.linalg.solve(j.T @ j + base, j.T @ (target - gap)[use])
        moved = gap + jac @ step
        below, above = ~use & (moved < floor - 1e-4), ~use & (moved > ceiling + 1e-4)
        if not (below.any() or above.any()):
            break
        target = np.where(above, ceiling, target)
        use |= below | above
    return _limit_step(step)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (K, 3) arrays (np.cross costs ten times more on a few rows)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _add_rows(jac: np.ndarray, arm_of: np.ndarray, about_shoulder: np.ndarray, about_elbow: np.ndarray,
              axis: np.ndarray, direction: np.ndarray, sign: float) -> None:
    """Add to rows of jac (K, 8, C-contiguous: written through a (K, 2, 4) view) how the gaps
    along direction (K, 3) grow with each arm's unknowns for points moved about the shoulder
    (levers (K, 3)) and the elbow (levers, axes)."""
    k = np.arange(len(arm_of))
    by_arm = jac.reshape(len(jac), 2, 4)  # a view: rows, arm, unknown
    # n . (w x r) = w . (r x n); for the flexion w = theta * axis.
    by_arm[k, arm_of, :3] += sign * _cross(about_shoulder, direction)
    by_arm[k, arm_of, 3] += sign * np.einsum("ki,ki->k", axis, _cross(about_elbow, direction))
