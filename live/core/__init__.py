"""The core: errors, skeleton topology, rotations, kinematics, frames, depth geometry, rings and the
Source / Stage / Sink protocols. It imports nothing from the rest of livecap."""
