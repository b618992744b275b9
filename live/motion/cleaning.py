"""Cut what a clip holds before its take (a leading bind pose, settling frames) so that it plays
as a performance (``trim_bind_pose``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from live.motion.clips import Motion

#: Mean joint speed (m/s) between two frames that no performed motion reaches: fast martial-arts
#: strikes in ../shared/data/bvh peak at 9 m/s at 120 fps, a bind-pose frame leaves at 15-160.
BIND_POSE_JUMP_MPS = 12.0
#: A take's first LEADING_GLITCH_S may also hold a settling frame or two after the bind pose that
#: the take leaves slower than a bind pose but faster than anything it does later: a step above
#: GLITCH_MIN_MPS and GLITCH_RATIO x the fastest step of the rest of the take (mb_16_15: 7.2 m/s,
#: then never above 1.3; mb_08_07: 11.0, then 2.3).
LEADING_GLITCH_S = 0.25
GLITCH_MIN_MPS = 3.0
GLITCH_RATIO = 3.0


def trim_bind_pose(motion: Motion, jump_mps: float = BIND_POSE_JUMP_MPS) -> Motion:
    """The motion without the leading frames it leaves faster than a body moves (mean joint speed
    above ``jump_mps``). Some exporters put the rig's bind pose (a T-pose, often at the origin)
    before the take: 76 of the 119 clips of ../shared/data/bvh (most MotionBuilder and DAZ
    conversions) start with one, and the take then teleports every joint within a frame, which
    no performer does and no online tracker can follow. Whoever plays a clip as a performance
    (evaluation, synthetic sessions) cuts them; ``load_motion`` keeps every frame, so files read
    back as written. Then the frames before a leading glitch: a step in the take's first
    ``LEADING_GLITCH_S`` faster than ``GLITCH_MIN_MPS`` and ``GLITCH_RATIO`` times the fastest
    step of the rest of the take (settling frames between bind pose and take: 6 of the shared
    clips, docs/motion.md). The mapping's reference pose was chosen before the cut, so rest joints and
    rotations are unchanged; a clip of such frames only is returned as it is."""
    if motion.num_frames < 2:
        return motion
    speed = np.linalg.norm(np.diff(motion.joints, axis=0), axis=-1).mean(axis=1) * motion.fps
    first = 0
    while first < len(speed) and speed[first] > jump_mps:
        first += 1
    # Then a leading glitch: a step early in the take much faster than all the take does after.
    head = max(int(round(LEADING_GLITCH_S * motion.fps)), 1)
    if len(speed) > first + 2 * head:
        later = float(speed[first + head:].max())
        glitch = np.flatnonzero(speed[first:first + head] > max(GLITCH_MIN_MPS, GLITCH_RATIO * later))
        if len(glitch):
            first += int(glitch[-1]) + 1
    if first == 0 or first >= motion.num_frames - 1:
        return motion
    return replace(motion, joints=motion.joints[first:], rotations=motion.rotations[first:],
                   root=motion.root[first:])
