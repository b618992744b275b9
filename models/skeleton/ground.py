"""Which way is up, and where the floor is, for a camera whose extrinsics nobody gave.

The skeleton stage works in a world frame with +y up and the floor at y = 0. Sources, in order
of trust (``GroundEstimator.camera_to_world``):

1. ``given``: the frame's own camera_to_world (a calibrated rig, a synthetic session), checked
   against the room (``GroundEstimator.check_given``): a floor in view lying more than 8 cm off
   its floor or tilted more than 6 degrees from it, or walls more than 5 degrees off vertical in
   it, turn its up (``given+floor``, ``given+wall``). A pose given by hand ("level, 1.2 m high") is often a
   few degrees off, and the regressor reads the body against the floor: 3 degrees of pitch at 3
   m puts the floor 16 cm off under the performer, and PCK@10cm falls from 0.78 to 0.62-0.70;
2. ``imu``: the camera's accelerometer (gravity measured while the camera is still) gives up;
   the floor height then comes from a floor plane at that orientation, or from the performer;
3. ``floor``: a floor plane wherever one is visible (a small patch in the bottom rows, behind
   the performer): the lowest large plane within ``max_tilt_deg`` of the level camera's up;
4. ``wall``: no floor in view, but a wall: walls are vertical, so up lies in the wall's plane
   (a wall ahead gives the camera's pitch, a wall beside its roll; ``find_wall``), the floor
   placed under the performer;
5. ``level``: no floor and no wall in view (a close-up at a desk, a floor the sensor does not
   return): a level camera, refined by the performer's own vertical axis when the whole body is
   seen, and the floor placed under the performer (``floor_under_person``).

Pure functions for the geometry; ``GroundEstimator`` keeps the estimate for a static camera,
re-checks it every ``recheck_s`` and records each change of source (for stats.json).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from live.core.rotations import angle_deg, quat_between, quat_to_matrix

#: Up in the camera frame (OpenCV axes: x right, y down, z forward) of a level camera.
LEVEL_UP = np.array([0.0, -1.0, 0.0])
#: The stature a performer is assumed to have when only their upper body is seen (the top of the
#: head 1.70 m above the floor): the network then sees a standing person of average height.
ASSUMED_STATURE_M = 1.70
#: A cluster at least this tall is a whole body: its lowest points are the feet.
WHOLE_BODY_M = 1.35
#: A cluster ending inside the image and at least this tall stands on its feet (a crouch, a
#: seated performer seen whole); shorter, it may be an upper body behind a desk.
CROUCH_M = 0.9
#: How far the floor lies below the lowest 1 % of a performer's points with no floor in view: the
#: finder drops what lies within its floor margin of the lowest points, and few points fall on the
#: soles. On the real Xtion frames (floor only in the bottom rows, up from a wall) the floor 0.3-0.5
#: m around the feet lies 3 cm below that quantile; on our own renderer's standing sessions 9-13
#: cm, on another renderer's 5 cm (docs/skeleton.md): the real sensor's figure.
FEET_BELOW_LOWEST_M = 0.03


def camera_to_world_from_up(up_cam: np.ndarray, height_m: float) -> np.ndarray:
    """(4, 4) camera -> world for a camera whose world up, in camera axes, is ``up_cam`` and
    whose centre is ``height_m`` above the floor: world +y up, the camera looking along world -z
    (its heading), floor at y = 0."""
    up = np.asarray(up_cam, np.float64)
    up = up / np.linalg.norm(up)
    forward = np.array([0.0, 0.0, 1.0]) - up * up[2]
    if np.linalg.norm(forward) < 1e-6:  # looking straight up or down: any heading will do
        forward = np.array([0.0, -1.0, 0.0]) - up * up[1]
    forward /= np.linalg.norm(forward)
    z_axis = -forward
    x_axis = np.cross(up, z_axis)
    m = np.eye(4)
    m[:3, :3] = np.stack([x_axis, up, z_axis])  # rows: world axes in camera coordinates
    m[:3, 3] = (0.0, height_m, 0.0)
    return m


def find_floor(points_cam: np.ndarray, up_prior: np.ndarray = LEVEL_UP, max_tilt_deg: float = 50.0,
               distance_m: float = 0.02, min_points: int = 150, below_share: float = 0.03,
               max_planes: int = 4, seed: int = 0) -> tuple[np.ndarray, float] | None:
    """The floor of a camera-frame cloud (M, 3): (up, the camera's height above it), or None.

    Planes are found by RANSAC (``ransac_plane``), up to ``max_planes`` of them, each on what the
    previous ones left. A plane is a floor candidate when its normal is within ``max_tilt_deg`` of
    ``up_prior``, it holds ``min_points`` points or more, and no more than ``below_share`` of the
    cloud lies more than 10 cm below it (a table top or a seat has the floor and legs below it;
    the floor has nothing). The lowest candidate wins. Any part of the image may hold it: a
    patch in the bottom rows, the floor behind the performer."""
    pts = np.asarray(points_cam, np.float64)
    if len(pts) < min_points:
        return None
    rng = np.random.default_rng(seed)
    prior = np.asarray(up_prior, np.float64) / np.linalg.norm(up_prior)
    cand = pts[rng.choice(len(pts), 20000, replace=False)] if len(pts) > 20000 else pts
    # Points far above the camera are never floor (the camera is at least a few cm above it).
    cand = cand[cand @ prior < 0.0]
    best: tuple[np.ndarray, float] | None = None
    min_support = max(min_points, int(0.02 * len(cand)))
    for _ in range(max_planes):
        if len(cand) < min_support:
            break
        n, d, inliers = ransac_plane(cand, distance_m, 200, rng)
        if n @ prior < 0:
            n, d = -n, -d
        if len(inliers) >= min_support and angle_deg(n, prior) <= max_tilt_deg and d > 0.05:
            heights = pts @ n + d  # signed height of every point above the plane
            if float(np.mean(heights < -0.10)) <= below_share and (best is None or d > best[1]):
                best = (n, d)  # lower plane = larger camera height above it
        keep = np.ones(len(cand), bool)
        keep[np.asarray(inliers, np.int64)] = False
        cand = cand[keep]
    return best


def find_wall(points_cam: np.ndarray, up_prior: np.ndarray = LEVEL_UP, **wall) -> np.ndarray | None:
    """Up (camera axes) from the largest wall of a camera-frame cloud (M, 3) (``wall_normals``),
    or None. For a wall that faces the camera, up along it and across the camera's x axis (a
    camera pitched but not rolled, as the level prior assumes: the wall gives the pitch); for a
    wall beside, ``up_prior`` turned into the wall's plane (the wall gives the roll)."""
    walls = wall_normals(points_cam, up_prior, **wall)
    if not walls:
        return None
    n = walls[0]
    prior = np.asarray(up_prior, np.float64) / np.linalg.norm(up_prior)
    along_rows = np.cross(n, np.array([1.0, 0.0, 0.0]))  # in the wall and across the camera's x
    if np.linalg.norm(along_rows) >= 0.5:  # within 60 degrees of facing the camera
        up = along_rows / np.linalg.norm(along_rows)
    else:
        up = into_plane(prior, n)
    return up if up @ prior > 0 else -up


def into_plane(up: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``up`` turned into the plane of unit ``normal`` (the least turn that makes it vertical)."""
    v = np.asarray(up, np.float64) - (np.asarray(up, np.float64) @ normal) * normal
    return v / np.linalg.norm(v)


def up_from_walls(walls: list[np.ndarray], up_prior: np.ndarray) -> np.ndarray:
    """Up (camera axes) that every wall of unit normals ``walls`` (largest first) holds: along
    the line two walls at least 30 degrees apart share (a corner gives the whole of up), else
    ``up_prior`` turned into the largest wall's plane (one wall gives one angle: a wall ahead the
    pitch, a wall beside the roll)."""
    prior = np.asarray(up_prior, np.float64)
    for other in walls[1:]:
        line = np.cross(walls[0], other)
        if np.linalg.norm(line) >= np.sin(np.radians(30.0)):
            line /= np.linalg.norm(line)
            return line if line @ prior > 0 else -line
    return into_plane(prior, walls[0])


def wall_normals(points_cam: np.ndarray, up_prior: np.ndarray = LEVEL_UP, max_tilt_deg: float = 35.0,
                 distance_m: float = 0.02, min_share: float = 0.08, min_width_m: float = 1.5,
                 min_height_m: float = 1.0, min_fill: float = 0.4, max_planes: int = 4, seed: int = 0
                 ) -> list[np.ndarray]:
    """The unit normals (camera axes) of the walls of a camera-frame cloud (M, 3), largest first.

    A wall is a plane found by RANSAC (up to ``max_planes``, each on what the previous left, within
    ``distance_m`` and the noise at the cloud's median range) whose
    normal is within ``max_tilt_deg`` of horizontal by ``up_prior`` (a camera pitched or rolled
    more than that from level sees its floor within that angle of its up, and its walls beyond:
    neither is taken for the other), holding ``min_share`` of the cloud, and whose points span at
    least ``min_width_m`` across ``up_prior`` and ``min_height_m`` along it (a performer's torso
    near the camera is a plane too, but neither that wide nor that tall), and whose points fill
    at least ``min_fill`` of that extent (a plane that cuts across a corner holds two lines of
    the walls, not a surface; ``_fill``)."""
    pts = np.asarray(points_cam, np.float64)
    prior = np.asarray(up_prior, np.float64) / np.linalg.norm(up_prior)
    min_support = max(150, int(min_share * len(pts)))
    if len(pts) < min_support:
        return []
    rng = np.random.default_rng(seed)
    cand = pts[rng.choice(len(pts), 20000, replace=False)] if len(pts) > 20000 else pts
    min_support = max(150, int(min_share * len(cand)))
    # Inliers within distance_m + 4 mm x z^2 at the cloud's median range: a far wall's depth
    # noise and steps (several cm at 5 m) would otherwise slice it into thin tilted layers.
    tolerance = distance_m + 0.004 * float(np.median(cand[:, 2])) ** 2
    walls: list[tuple[int, np.ndarray]] = []
    for _ in range(max_planes):
        if len(cand) < min_support:
            break
        n, _, inliers = ransac_plane(cand, tolerance, 200, rng)
        # A plane square to the optical axis says nothing the level prior does not (the up it
        # gives is the prior's), and the flat steps of a stereo camera's quantised far depth are
        # such planes: they are skipped, so that they do not hide a wall that says more.
        square = abs(float(n[2])) > np.cos(np.radians(3.0))
        if (len(inliers) >= min_support and abs(float(n @ prior)) <= np.sin(np.radians(max_tilt_deg))
                and not square):
            on = cand[inliers]
            along = on @ prior
            across_dir = np.cross(n, prior)
            across = on @ (across_dir / np.linalg.norm(across_dir))
            a0, a1 = np.quantile(across, (0.02, 0.98))
            h0, h1 = np.quantile(along, (0.02, 0.98))
            if a1 - a0 >= min_width_m and h1 - h0 >= min_height_m and _fill(across, along, (a0, a1, h0, h1)) >= min_fill:
                walls.append((len(inliers), n))
        keep = np.ones(len(cand), bool)
        keep[np.asarray(inliers, np.int64)] = False
        cand = cand[keep]
    return [n for _, n in sorted(walls, key=lambda w: -w[0])]


def _fill(u: np.ndarray, v: np.ndarray, box: tuple[float, float, float, float], cell_m: float = 0.25) -> float:
    """The share of the cells (``cell_m`` square) of ``box`` (u0, u1, v0, v1) that hold a point
    (u, v) of a plane's inliers."""
    u0, u1, v0, v1 = box
    nu, nv = max(int(np.ceil((u1 - u0) / cell_m)), 1), max(int(np.ceil((v1 - v0) / cell_m)), 1)
    inside = (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
    iu = np.minimum(((u[inside] - u0) / cell_m).astype(np.intp), nu - 1)
    iv = np.minimum(((v[inside] - v0) / cell_m).astype(np.intp), nv - 1)
    return len(np.unique(iu * nv + iv)) / (nu * nv)


def turned_to_up(given: np.ndarray, up_cam: np.ndarray, height_m: float | None = None) -> np.ndarray:
    """(4, 4) camera -> world: ``given`` turned about the camera's centre the least way that makes
    ``up_cam`` (camera axes) its world up (the heading kept), the camera ``height_m`` above the
    floor (None: as given)."""
    c2w = np.array(given, np.float64)
    up_world = c2w[:3, :3] @ (np.asarray(up_cam, np.float64) / np.linalg.norm(up_cam))
    c2w[:3, :3] = quat_to_matrix(quat_between(up_world, np.array([0.0, 1.0, 0.0]))) @ c2w[:3, :3]
    if height_m is not None:
        c2w[1, 3] = height_m
    return c2w


def ransac_plane(points: np.ndarray, distance_m: float, iterations: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, float, np.ndarray]:
    """The plane n . p + d = 0 (unit n) with the most points (M, 3) within ``distance_m``, refined by
    a least-squares fit to those inliers, and their indices. Deterministic for a given ``rng``
    (open3d's multi-threaded segment_plane is not, and replays must give the same bytes)."""
    m = len(points)
    picks = rng.integers(0, m, size=(iterations, 3))
    a, b, c = points[picks[:, 0]], points[picks[:, 1]], points[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    normals, a = normals[ok] / norms[ok, None], a[ok]
    if not len(normals):
        return np.array([0.0, -1.0, 0.0]), 0.0, np.zeros(0, np.int64)
    offsets = -np.einsum("ij,ij->i", normals, a)
    # Count inliers on a fixed subsample (the counts only rank the hypotheses).
    probe = points if m <= 4000 else points[rng.choice(m, 4000, replace=False)]
    counts = (np.abs(probe @ normals.T + offsets) <= distance_m).sum(axis=0)
    best = int(np.argmax(counts))
    n, d = normals[best], float(offsets[best])
    inliers = np.flatnonzero(np.abs(points @ n + d) <= distance_m)
    if len(inliers) >= 3:  # least squares through the inliers: the noise averages out
        sel = points[inliers]
        centre = sel.mean(axis=0)
        _, _, vt = np.linalg.svd(sel - centre, full_matrices=False)
        refit = vt[2] if vt[2] @ n >= 0 else -vt[2]
        n, d = refit, float(-refit @ centre)
        inliers = np.flatnonzero(np.abs(points @ n + d) <= distance_m)
    return n, d, inliers


def body_up(points_world: np.ndarray, up: np.ndarray, max_tilt_deg: float = 25.0,
            min_elongation: float = 2.5) -> np.ndarray | None:
    """The vertical axis of a standing person's points (M, 3), in the frame of ``up`` (the
    current up, same frame as the points): their longest principal axis, turned toward ``up``,
    when it is clearly the longest (``min_elongation`` x the second) and within
    ``max_tilt_deg`` of ``up``; else None (a close-up, a crouch, arms outstretched)."""
    pts = np.asarray(points_world, np.float64)
    if len(pts) < 50:
        return None
    centred = pts - pts.mean(axis=0)
    evals, evecs = np.linalg.eigh(centred.T @ centred / len(pts))
    axis = evecs[:, 2]
    if evals[2] < min_elongation ** 2 * max(evals[1], 1e-12):
        return None
    if axis @ up < 0:
        axis = -axis
    return axis if angle_deg(axis, up) <= max_tilt_deg else None


def floor_under_person(y_low: float, y_top: float, cut_below: bool = False) -> float:
    """The floor's height (in the current world y) under a person whose points span y_low..y_top
    with no floor in view: under their feet when the body ends inside the image (not
    ``cut_below`` by its bottom edge) and is at least a crouch's height, or when the whole body
    is seen; else (a close-up, an upper body behind a desk) ASSUMED_STATURE_M below the top of
    their head."""
    extent = y_top - y_low
    feet = y_low - FEET_BELOW_LOWEST_M
    if extent >= WHOLE_BODY_M or (not cut_below and extent >= CROUCH_M):
        return feet
    return min(feet, y_top - ASSUMED_STATURE_M)


@dataclass
class GroundEstimator:
    """The world frame of a camera without extrinsics, kept while the camera stays still.

    ``gravity_up``: world up in camera axes from the camera's IMU (set by the skeleton stage),
    or None. ``camera_height_m``: the camera's height above the floor as the user measured it,
    or None: used while no floor is in view and the IMU gives up (``known_height``), instead of
    a floor guessed under the performer (a seated performer at a desk would get a standing one's
    floor). Without an IMU, up is itself a guess there, and a fixed height under a tilted up
    placed the performer worse than the guess (docs/results.md). ``recheck_s``: how often
    the floor is searched again (a camera picked up and put down elsewhere; a floor that came
    into view). ``changes``: (t_ns, source) at each change."""

    recheck_s: float = 2.0
    check_given_pose: bool = True
    gravity_up: np.ndarray | None = None
    camera_height_m: float | None = None
    source: str | None = None
    changes: list[tuple[int, str]] = field(default_factory=list)
    searches: int = 0
    _up: np.ndarray | None = None  # up in camera axes (floor, imu or level + body axis)
    _height: float | None = None  # camera height above the floor, when a floor is seen
    _body_up: np.ndarray | None = None  # the performer's axis blended over frames (level camera)
    _checked_ns: int | None = None
    _given_fix: np.ndarray | None = None  # world correction: the room's camera_to_world = fix @ given

    #: A given pose is turned to the room's when the floor in view lies more than GIVEN_SHIFT_M
    #: off its floor (the median height of the found floor's points in the given world: where the
    #: floor is seen, not extrapolated to under the camera, where a far patch's half a degree of
    #: noise makes several cm) or is tilted more than GIVEN_TURN_DEG from it; or when no floor is
    #: in view and a wall is more than GIVEN_WALL_TURN_DEG off vertical in it. A found floor more
    #: than GIVEN_MAX_TILT_DEG or GIVEN_MAX_SHIFT_M (under the camera) from the given one is
    #: another surface (a ramp, a stage, a table).
    GIVEN_SHIFT_M = 0.08
    GIVEN_TURN_DEG = 6.0
    GIVEN_WALL_TURN_DEG = 5.0
    GIVEN_MAX_TILT_DEG = 15.0
    GIVEN_MAX_SHIFT_M = 0.5

    #: A new estimate replaces the one in use only when it moved this much: every change of the
    #: rotation costs the finder its cached rays (a few ms), and sub-degree wobble is noise.
    MIN_TURN_DEG = 0.5
    MIN_SHIFT_M = 0.01

    def due(self, t_ns: int) -> bool:
        """Whether the floor is to be searched again at ``t_ns``."""
        return (self._checked_ns is None or t_ns < self._checked_ns
                or t_ns - self._checked_ns >= self.recheck_s * 1e9)

    def use_given(self, t_ns: int) -> None:
        """The frames carry their own extrinsics, taken as they are."""
        self._given_fix = None
        self._set_source(t_ns, "given")

    def check_given(self, t_ns: int, given: np.ndarray, points_cam: np.ndarray | None,
                    finer: Callable[[], np.ndarray] | None = None) -> None:
        """Check a frame's own extrinsics against the room when due (``points_cam``: its camera
        points; ``finer`` as in ``update``): a floor in view within GIVEN_MAX_TILT_DEG and
        GIVEN_MAX_SHIFT_M of the given one, else the largest wall. When it disagrees, the given
        pose is turned about the camera to the room's up until the next check: to the floor's
        up and height (``given+floor``), or to the wall's up (``given+wall``; a pose wrong in up
        is not trusted in height either: the floor is then placed under the performer, as with
        no floor in view, ``floor_unknown``). When it agrees, the pose is used as given; with
        neither in view the last verdict stands."""
        if not self.check_given_pose:
            self.use_given(t_ns)
            return
        if not self.due(t_ns) or points_cam is None:
            if self.source is None:
                self._set_source(t_ns, "given")
            return
        self._checked_ns = t_ns
        self.searches += 1
        given = np.asarray(given, np.float64)
        prior, height = given[1, :3] / np.linalg.norm(given[1, :3]), float(given[1, 3])

        def floor_in(pts: np.ndarray) -> tuple[np.ndarray, float] | None:
            found = find_floor(pts, prior, max_tilt_deg=self.GIVEN_MAX_TILT_DEG)
            return found if found is not None and abs(found[1] - height) <= self.GIVEN_MAX_SHIFT_M else None

        floor = floor_in(points_cam)
        if floor is None and finer is not None:
            points_cam = finer()
            floor = floor_in(points_cam)
        if floor is not None:
            up, floor_height = floor
            on_floor = points_cam[np.abs(points_cam @ up + floor_height) <= 0.02]
            lies = float(np.median(on_floor @ given[1, :3] + height))  # its height in the given world
            off = angle_deg(up, prior) > self.GIVEN_TURN_DEG or abs(lies) > self.GIVEN_SHIFT_M
            self._given_verdict(t_ns, given, turned_to_up(given, up, floor_height) if off else None, "given+floor")
            return
        walls = wall_normals(points_cam, prior)
        if walls:
            up = up_from_walls(walls, prior)
            self._given_verdict(t_ns, given, turned_to_up(given, up) if angle_deg(up, prior) > self.GIVEN_WALL_TURN_DEG
                                else None, "given+wall")
        elif self.source is None:
            self._set_source(t_ns, "given")

    def _given_verdict(self, t_ns: int, given: np.ndarray, turned: np.ndarray | None, source: str) -> None:
        """Take a check's verdict: the given pose ``turned`` to the room (None: it agrees)."""
        if turned is None:
            self._given_fix = None
            self._set_source(t_ns, "given")
            return
        fix = turned @ np.linalg.inv(given)
        if self._given_fix is None or angle_deg(fix[:3, 1], self._given_fix[:3, 1]) > self.MIN_TURN_DEG or \
                np.abs(fix[:3, 3] - self._given_fix[:3, 3]).max() > self.MIN_SHIFT_M:
            self._given_fix = fix
        self._set_source(t_ns, source)

    @property
    def floor_unknown(self) -> bool:
        """No floor to stand the performer on: no extrinsics and no floor in view, or given
        extrinsics turned to a wall's up (their height is not trusted then)."""
        return self.source == "given+wall" or (not (self.source or "").startswith("given") and not self.floor_seen)

    @property
    def given_fix(self) -> np.ndarray | None:
        """(4, 4) the world correction of given extrinsics (the room's camera_to_world = this @
        the given one), or None when they are used as given."""
        return self._given_fix

    def room_from_given(self, given: np.ndarray) -> np.ndarray:
        """A frame's camera_to_world as the room shows it: the given one, corrected."""
        return np.asarray(given, np.float64) if self._given_fix is None else self._given_fix @ given

    @property
    def floor_seen(self) -> bool:
        return self._height is not None

    @property
    def known_height(self) -> float | None:
        """The given camera height, while the camera's IMU gives up; else None."""
        return self.camera_height_m if self.gravity_up is not None else None

    def up(self) -> np.ndarray:
        """The current up in camera axes."""
        if self._up is not None:
            return self._up
        return LEVEL_UP if self.gravity_up is None else np.asarray(self.gravity_up, np.float64)

    def update(self, t_ns: int, points_cam: np.ndarray | None,
               finer: Callable[[], np.ndarray] | None = None) -> None:
        """Search the floor again when due (``points_cam``: the frame's camera points, or None
        when there is nothing to search in; ``finer``: more points of the same view, searched
        when those hold no floor and no wall, e.g. a small image on a finer stride: a floor seen
        at a grazing angle may hold too few points on the coarse one)."""
        if not self.due(t_ns) or points_cam is None:
            return
        self._checked_ns = t_ns
        self.searches += 1
        prior = LEVEL_UP if self.gravity_up is None else np.asarray(self.gravity_up, np.float64)
        # With gravity the floor's normal is known to a few degrees; without it, any sane pitch.
        tilt = 8.0 if self.gravity_up is not None else 50.0
        floor = find_floor(points_cam, prior, max_tilt_deg=tilt)
        if floor is None and finer is not None:
            points_cam = finer()
            floor = find_floor(points_cam, prior, max_tilt_deg=tilt)
        if floor is not None:
            up, height = floor
            up = prior if self.gravity_up is not None else up
            if (self._up is None or self._height is None or angle_deg(up, self._up) > self.MIN_TURN_DEG
                    or abs(height - self._height) > self.MIN_SHIFT_M):
                self._up, self._height = up, height
            self._set_source(t_ns, "imu+floor" if self.gravity_up is not None else "floor")
            return
        self._height = None
        if self.gravity_up is not None:
            self._up = None
            self._set_source(t_ns, "imu")
            return
        wall_up = find_wall(points_cam)
        if wall_up is not None:
            if self._up is None or self.source != "wall" or angle_deg(wall_up, self._up) > self.MIN_TURN_DEG:
                self._up = wall_up
            self._body_up = None
            self._set_source(t_ns, "wall")
        else:
            if self.source not in ("level", "level+body"):
                self._up = self._body_up = None
            self._set_source(t_ns, self.source if self.source in ("level", "level+body") else "level")

    def refine_with_body(self, t_ns: int, axis: np.ndarray | None, weight: float = 0.1) -> None:
        """Blend the performer's vertical axis (camera axes) into a level camera's up."""
        if axis is None or self.gravity_up is not None or self.floor_seen or self.source in ("wall", "given+wall"):
            return
        current = self.up() if self._body_up is None else self._body_up
        blended = current * (1.0 - weight) + np.asarray(axis, np.float64) * weight
        self._body_up = blended / np.linalg.norm(blended)
        if angle_deg(self._body_up, self.up()) > self.MIN_TURN_DEG:
            self._up = self._body_up
        self._set_source(t_ns, "level+body")

    def camera_to_world(self, height_m: float) -> np.ndarray:
        """(4, 4) camera -> world at the current up: the floor's height when one is seen, else
        the given camera height with the IMU's up (``known_height``), else ``height_m`` (the
        caller's guess, refined from the performer)."""
        if self._height is not None:
            return camera_to_world_from_up(self.up(), self._height)
        known = self.known_height
        return camera_to_world_from_up(self.up(), height_m if known is None else known)

    def _set_source(self, t_ns: int, source: str) -> None:
        if source != self.source:
            self.source = source
            self.changes.append((int(t_ns), source))
