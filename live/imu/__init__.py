"""IMU suit -> skeleton (layout, calibration, suit solver) and depth + IMU fusion.

Modules: ``layout`` (sensor id -> segment), ``calibration`` (held T-/N-pose -> offsets and
heading), ``suit_skeleton`` (segment rotations -> 22 local rotations, foot odometry),
``fusion`` (depth skeleton + IMUs), ``stage`` (pipeline stages and ``build_stages``).
See docs/imu.md.
"""
