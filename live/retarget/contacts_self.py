"""The performer's self-contacts, frame by frame: hand-hand, hand-head, hand-torso, hand-leg and
forearm-torso, from the performer's body surface (live/retarget/contacts_surface.py).

For every probe set (a hand, a forearm) and every region it may touch (torso, head, each leg,
the other hand), the gap is the least distance of the set's probes to the region's skin
(negative when they sink in). A pair is in
contact from when its gap falls below ``on`` (1 cm) until it rises above ``off`` (2 cm): the
hysteresis keeps a hand resting on a hip in contact through the jitter of a depth skeleton. A
pair's weight ramps to 1 over ``blend_s`` seconds after the contact starts and back to 0 after it
ends (smoothstep), so the avatar's correction never jumps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.retarget.contacts_surface import ALL_PROBES, PROBES, REGIONS, BodySurface, measure

#: The gap reported for a pair whose part is too far to be measured (m).
FAR_GAP = 1.0


@dataclass(frozen=True)
class ContactSettings:
    """on / off: gaps (m) that start and end a contact; blend_s: the weight's ramp (s); tau: the
    length (m) of the softmin that weighs a gap's direction and point; reach: parts whose bounding sphere is within this (m) of a probe set's
    are measured; margin: how far out of the avatar's skin hands and forearms are kept (m);
    clearance: a hand the performer does not rest on a part is kept at least min(the
    performer's gap, clearance) from it on the avatar (m), so that it does not touch where the
    performer did not; touch: a contact is kept touching (at the margin) on the avatar rather
    than at the performer's gap (for a performer whose gaps are mostly error: ``ESTIMATED``);
    let_go: an arm holding no contact lets its correction go at ``blend_s`` where nothing is in
    its way, rather than only at the damped steps' pace (live/retarget/contacts_keep.py)."""

    on: float = 0.010
    off: float = 0.020
    blend_s: float = 0.15
    tau: float = 0.003
    reach: float = 0.04
    margin: float = 0.004
    clearance: float = 0.012
    touch: bool = False
    let_go: bool = True


#: For a performer known by the depth stage's skeleton: its gaps carry the skeleton's error
#: (centimetres; and a fitted template's girth), so a contact starts and ends at wider gaps
#: (measured farther) and is kept touching. On the tuning takes from depth, hand contacts kept /
#: precision: 39.7 / 49.5 % with the defaults, 60.2 / 58.3 at 2.5 / 4 cm, 67.8 / 59.1 at 3.2 /
#: 4.5, 67.6 / 61.1 here; touching alone 44.8 / 49.1, the wider gaps alone 40.2 / 46.0
#: (docs/results.md, "Self-contacts"). Not for exact skeletons (a BVH take, the suit, the
#: fusion): from exact skeletons on a fitted template they keep 98.6 % of the hand contacts
#: against 92.3 %, at 78.7 % precision against 98.6 %. A correction is held between contacts
#: (``let_go`` off): an estimate's contacts drop out and come back, and on the tuning takes from
#: depth letting go kept fewer of the clapping's contacts (46 -> 26 % on the child, 26 -> 18 % on
#: the heavy adult; all takes 67.6 -> 65.7 %).
ESTIMATED = ContactSettings(on=0.04, off=0.055, reach=0.06, touch=True, let_go=False)


def settings_for(from_depth: bool) -> ContactSettings:
    """The contact settings for a performer's skeleton: ESTIMATED behind the depth stage, the
    exact ones otherwise (the truth, a BVH take, the suit, the fusion)."""
    return ESTIMATED if from_depth else ContactSettings()


@dataclass
class SourceContacts:
    """One frame of the performer's contacts, indexed [probe set, region] (PROBES x REGIONS):
    gap (m, FAR_GAP when not measured), contact (bool, with hysteresis), weight (ramped)."""

    gap: np.ndarray
    contact: np.ndarray
    weight: np.ndarray

    @property
    def hand_contacts(self) -> list[tuple[str, str]]:
        """(probe set, region) names of the hands' contacts on this frame."""
        return [(PROBES[i].name, REGIONS[k]) for i, k in zip(*np.nonzero(self.contact))
                if PROBES[i].kind == "hand"]


def measure_gaps(surface: BodySurface, glob: np.ndarray, pos: np.ndarray, settings: ContactSettings,
                 probes: np.ndarray | None = None) -> np.ndarray:
    """(PROBES, REGIONS) gaps of the probe sets ``probes`` (default all) to every region they are
    tested against in a pose (glob (22, 3, 3), pos (22, 3)); FAR_GAP for regions beyond the broad
    phase's reach and for the probe sets not measured."""
    gaps = np.full((len(PROBES), len(REGIONS)), FAR_GAP)
    found = measure(surface, glob, pos, ALL_PROBES if probes is None else probes, settings.reach, settings.tau)
    gaps[found.probe, found.region] = found.gap
    return gaps


class SelfContactDetector:
    """Online self-contacts of the performer with hysteresis and ramped weights; ``probes``: the
    probe sets whose contacts are wanted (default all; the others never touch)."""

    def __init__(self, settings: ContactSettings = ContactSettings(), probes: np.ndarray | None = None):
        self.settings = settings
        self.probes = None if probes is None else np.asarray(probes, np.int64)
        self.reset()

    def reset(self) -> None:
        shape = (len(PROBES), len(REGIONS))
        self.contact = np.zeros(shape, bool)
        self.ramp = np.zeros(shape)

    def update(self, surface: BodySurface, glob: np.ndarray, pos: np.ndarray, dt: float) -> SourceContacts:
        """One frame of the performer: its surface, global rotations (22, 3, 3) and joints (22, 3);
        dt seconds since the frame before."""
        return self.step(measure_gaps(surface, glob, pos, self.settings, self.probes), dt)

    def step(self, gap: np.ndarray, dt: float) -> SourceContacts:
        """One frame's gaps (PROBES, REGIONS) through the hysteresis and the weights' ramps."""
        s = self.settings
        self.contact = (gap < s.on) | (self.contact & (gap <= s.off))
        step = min(max(dt, 0.0) / max(s.blend_s, 1e-6), 1.0)
        self.ramp = np.clip(self.ramp + np.where(self.contact, step, -step), 0.0, 1.0)
        weight = self.ramp * self.ramp * (3.0 - 2.0 * self.ramp)  # smoothstep: no velocity jump
        return SourceContacts(gap=gap, contact=self.contact.copy(), weight=weight)
