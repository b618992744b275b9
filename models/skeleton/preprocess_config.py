"""Settings of the person finder (``models.skeleton.preprocess.PersonFinder``): sample size and
strides, range limits, the occupancy grid, the person tests, the motion cue and tracking."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PreprocessConfig:
    num_points: int = 512
    pixel_stride: int = 2
    # Depth images: find the person on a coarser stride, then draw the sample from the person's
    # pixels at pixel_stride (the same points, ~4x less work). None: one pass at pixel_stride.
    coarse_stride: int | None = 4
    # Depth images: pixels with a 4-neighbour more than this share of their range nearer or
    # farther are left out of the sample (``depth_edges.edge_pixels``: mixed returns at the
    # silhouette). A regressor declares it in its card (``preprocess``), as it was trained
    # with it. None: every pixel.
    edge_jump_share: float | None = None
    min_range_m: float = 0.3
    max_range_m: float = 6.0
    floor_margin_m: float = 0.03
    seed_height_m: float = 0.2
    cell_m: float = 0.05
    grid_half_extent_m: float = 6.0
    min_points: int = 120
    min_height_m: float = 0.35
    max_height_m: float = 2.4
    min_narrow_top: float = 0.4
    max_footprint_m: float = 1.8
    # When no cluster passes, one too wide to be a person is searched again without its wall's
    # points (within wall_tolerance_m + 1 cm x range² of the vertical plane holding most of it):
    # a performer close to a wall, joined to it by noise or flying pixels. None: no second search.
    wall_tolerance_m: float | None = 0.05
    # Flat faces: a cluster with more than flat_share of its points within flat_tolerance_m of one
    # plane (a box, shelves, a figure of boxes) scores in proportion to the share off it, down to
    # flat_weight (``person_clusters.plane_share``). None: no such test.
    flat_share: float | None = 0.6
    flat_tolerance_m: float = 0.03
    flat_weight: float = 0.2
    background_margin_m: float = 0.10
    # Motion cue: a cluster whose depth has not changed since a frame motion_lag_s ago (or the
    # oldest frame kept, early on) scores static_weight times a moving one: furniture never
    # moves, a performer does. A point moved when it came nearer by more than
    # motion_change_m + 1 cm x z^2 (stereo noise grows with the square of the range; only nearer:
    # the wall a performer uncovers as they step aside did not move); a cluster
    # moves in proportion to its share of moved points above motion_noise_share (what noise and
    # flickering edges give a still surface), fully at motion_full_share. A still performer
    # next to still furniture gets no cue either way.
    motion_lag_s: float = 0.3
    motion_change_m: float = 0.05
    motion_noise_share: float = 0.15
    motion_full_share: float = 0.5
    static_weight: float = 0.1
    # A surface that went farther by up to motion_recede_m beyond the noise counts as moved too:
    # the same surface stepping back (a performer walking away shows nothing nearer). A larger
    # jump is what a performer uncovered behind them (a wall, a shelf), which did not move.
    # None: only what came nearer.
    motion_recede_m: float | None = 0.4
    # Tracking: a frame is searched only in a window around the previous person grown by
    # track_margin_m (at their depth) on each side; the whole image is searched when nobody was
    # tracked, when the window holds no person or cuts the one found, and every
    # track_full_search_s (another person or a missed performer is found within that time).
    # A window is used only once the motion cue compares frames motion_lag_s apart and after a
    # whole-image search agreed with the frame before it (the person within track_margin_m): a
    # first pick of clutter is not kept by its window.
    # None: every frame searches the whole image.
    track_margin_m: float | None = 0.5
    track_full_search_s: float = 1.0
    # Body check (with a judge, ``PersonFinder.find``): until the tracked person has been seen
    # moving, a pick whose sample lies farther than body_check_m on average from the bones of
    # the skeleton regressed from it is weighed against the best cluster of the rest of the
    # image, taken when that one fits within body_fit_m, better by body_fit_margin_m, is at
    # least body_min_height_m tall and has at least body_min_share of the pick's points (a chair
    # or a low box can fit a crouched skeleton well, a thin sliver of a door frame any skeleton).
    # Performers fit at 0.07-0.08 m (99 % within 0.14), still figures, shelves and sofas picked
    # instead at 0.12-0.30. None: no check.
    body_check_m: float | None = 0.14
    body_fit_m: float = 0.12
    body_fit_margin_m: float = 0.02
    body_min_height_m: float = 1.2
    body_min_share: float = 0.15
