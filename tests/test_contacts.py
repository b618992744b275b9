"""Self-contacts: the body surface, the performer's contacts with hysteresis, the avatar's
correction (contacts kept, hands and forearms out of the body, smooth), the stage and the CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from live.body.library import load_body
from live.core import assets
from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX
from live.retarget.contacts_self import ContactSettings, SelfContactDetector
from live.retarget.contacts_surface import (
    ALL_PROBES,
    PARTS,
    PROBES,
    REGIONS,
    body_surface,
    measure,
    signed_distances,
    skin_faces,
    vertex_normals,
    winding_numbers,
)

BVH = assets.bvh_dir()
needs_bvh = pytest.mark.skipif(not (BVH / "mb_49_11.bvh").is_file(), reason="needs ../shared/data/bvh")


def _rest_pose(body):
    return np.tile(np.eye(3), (22, 1, 1)), np.asarray(body.rest_joints, np.float64)


def test_part_grids_match_the_skin_in_the_rest_pose():
    """A part's grid distance (rigid, trilinear) against the exact distance to its skin."""
    body = load_body("child_boy_4y")
    surface = body_surface(body)
    glob, pos = _rest_pose(body)
    v = np.asarray(body.vertices, np.float64)
    faces = np.asarray(body.faces, np.int64)
    rng = np.random.default_rng(0)
    spine2 = PARTS.index(next(p for p in PARTS if p.name == "spine2"))
    member = np.asarray(body.weights)[:, JOINT_INDEX["spine2"]] >= 0.5
    pts = v[rng.choice(np.flatnonzero(member), 300)] + rng.normal(0.0, 0.01, (300, 3))
    grid_d = surface.distances(glob, pos, pts, np.array([spine2]))[0][0]
    part_faces = faces[(np.asarray(body.weights)[:, JOINT_INDEX["spine2"]] >= 0.25)[faces].any(1)]
    exact = signed_distances(v, vertex_normals(v, faces), part_faces, pts)[0]
    assert np.abs(grid_d - exact).mean() < 0.0015
    assert np.percentile(np.abs(grid_d - exact), 95) < 0.004


def test_winding_numbers_tell_inside_from_outside():
    body = load_body("child_boy_4y")
    v, f = np.asarray(body.vertices, np.float64), np.asarray(body.faces)
    pelvis = np.asarray(body.rest_joints[0], np.float64)
    w = winding_numbers(v, f, np.array([pelvis, pelvis + [0.0, 0.0, 1.0], pelvis + [0.0, 2.0, 0.0]]))
    assert w[0] == pytest.approx(1.0, abs=1e-6) and abs(w[1]) < 1e-6 and abs(w[2]) < 1e-6


def test_contacts_start_below_on_and_end_above_off():
    """Hysteresis: a gap hovering between on (1 cm) and off (2 cm) keeps a contact, not starts one;
    the weight ramps up over blend_s and back down after the contact ends."""
    settings = ContactSettings()
    det = SelfContactDetector(settings)
    gaps = [0.015, 0.012, 0.008, 0.015, 0.019, 0.015, 0.021, 0.015]
    states, weights = [], []
    for g in gaps:
        grid = np.full((len(PROBES), len(REGIONS)), 1.0)
        grid[0, REGIONS.index("torso")] = g
        out = det.step(grid, 1 / 30)
        states.append(bool(out.contact[0, REGIONS.index("torso")]))
        weights.append(float(out.weight[0, REGIONS.index("torso")]))
    assert states == [False, False, True, True, True, True, False, False]
    assert weights[2] > 0 and all(b >= a for a, b in zip(weights[2:6], weights[3:6]))
    assert weights[6] < weights[5] and weights[0] == 0.0


def _clip(name: str, start: int, count: int):
    from live.evaluation.retarget import prepare_motion

    m = prepare_motion(BVH / name, 30.0)
    return replace(m, joints=m.joints[start:start + count], rotations=m.rotations[start:start + count],
                   root=m.root[start:start + count])


def _retarget(motion, source, target, contacts: bool):
    from live.evaluation.contacts import run_retargeter
    from live.evaluation.retarget import make_retargeter, source_skeletons
    from live.retarget.contacts_retargeter import ContactRetargeter

    joints, rest, _ = source_skeletons(motion, source, "skeleton")
    rt = make_retargeter("analytic", rest, target.rest_joints, 30.0)
    if contacts:
        rt = ContactRetargeter(rt, body_surface(target), target.rest_joints, rest, body_surface(source))
    return run_retargeter(rt, joints), rt


@needs_bvh
def test_a_hand_sinking_into_a_heavy_belly_is_pushed_out_and_the_contact_kept():
    """Hands resting on the belly (CMU subject 49, curled in) on the heaviest avatar: without the
    correction they sink centimetres in; with it the contacts stay within 2 cm (once they have
    ramped in) and the hands no deeper than a few millimetres, measured on the skinned mesh."""
    from live.evaluation.contacts import REGIONS as EVAL_REGIONS
    from live.evaluation.contacts import BodyRegions, contact_geometry

    motion = _clip("mb_49_11.bvh", 190, 24)
    source, target = load_body("adult_male_average"), load_body("tall_heavy_male")
    regions = BodyRegions.of(target)
    faces = np.asarray(target.faces, np.int64)
    from live.body.skinning import lbs

    results = {}
    for contacts in (False, True):
        (root, rot, _), _ = _retarget(motion, source, target, contacts)
        gaps, depth = contact_geometry(regions, faces, lbs(target.vertices, target.weights, target.rest_joints, rot, root))
        results[contacts] = (gaps, depth)
    torso = list(EVAL_REGIONS).index("torso")
    hands_off = results[False][0][:, :, torso]
    hands_on = results[True][0][:, :, torso]
    assert hands_off.min() < -0.02  # sinks in by more than 2 cm without
    assert hands_on.min() > -0.008
    # The contacts are kept once their weight has ramped in (the take starts with the hand
    # deep in the belly and in the other forearm: both are pushed out first).
    ramp = int(np.ceil(ContactSettings().blend_s * 30))
    assert np.all(hands_on[ramp:][hands_off[ramp:] < 0.01] < 0.02)


@needs_bvh
def test_nothing_near_leaves_the_pose_exactly_as_the_retargeter_made_it():
    """A walk's first frames with the arms away from the body: bit-identical to no correction."""
    motion = _clip("cc_007_01.bvh", 0, 1)
    source, target = load_body("adult_male_average"), load_body("child_boy_9y")
    t_pose = replace(motion, rotations=np.tile([1.0, 0, 0, 0], (1, 22, 1)).astype(np.float32),
                     joints=(np.asarray(source.rest_joints)[None]).astype(np.float32))
    (root_a, rot_a, j_a), _ = _retarget(t_pose, source, target, False)
    (root_b, rot_b, j_b), rt = _retarget(t_pose, source, target, True)
    assert np.array_equal(rot_a, rot_b) and np.array_equal(j_a, j_b) and rt.counters["frames_corrected"] == 0


@needs_bvh
def test_the_correction_follows_the_motion_smoothly():
    """The wrists' correction never jumps: frame to frame it changes by at most the rate limit
    (MAX_HAND_SPEED plus INPUT_SHARE of the uncorrected wrist's own speed), and the corrected
    motion's acceleration stays near the uncorrected one's."""
    from live.retarget.contacts_keep import INPUT_SHARE, MAX_HAND_SPEED

    motion = _clip("mb_16_15.bvh", 0, 90)
    source, target = load_body("adult_male_average"), load_body("tall_heavy_male")
    (_, _, off), _ = _retarget(motion, source, target, False)
    (_, _, on), _ = _retarget(motion, source, target, True)
    wrists = [JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]]
    correction = on[:, wrists] - off[:, wrists]
    step = np.linalg.norm(np.diff(correction, axis=0), axis=-1)
    speed = np.linalg.norm(np.diff(off[:, wrists], axis=0), axis=-1)
    assert correction.any() and np.all(step <= (MAX_HAND_SPEED / 30.0 + INPUT_SHARE * speed) * 1.5 + 1e-4)
    acc = lambda j: np.linalg.norm(j[2:] - 2 * j[1:-1] + j[:-2], axis=-1).mean()  # noqa: E731
    assert acc(on) < acc(off) + 0.003


def test_measure_finds_the_other_hand_when_the_hands_touch():
    """The right hand (and its forearm) moved over the left hand: the left hand's gap to the right
    hand's or arm's skin is negative; the regions are cut by the skin's heaviest weights."""
    body = load_body("child_boy_9y")
    surface = body_surface(body)
    glob, pos = _rest_pose(body)
    pos = pos.copy()
    rest = np.asarray(body.vertices, np.float64)  # the rest pose: probes where the mesh has them
    left, right = rest[surface.model.probes[0]], rest[surface.model.probes[1]]
    shift = left[:, 0].min() - right[:, 0].max()
    pos[JOINT_INDEX["right_wrist"]] += [shift - 0.04, 0.0, 0.0]
    pos[JOINT_INDEX["right_elbow"]] += [shift - 0.04, 0.0, 0.0]
    gaps = measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003)
    rows = np.flatnonzero((gaps.probe == 0) & np.isin(gaps.region, [REGIONS.index("right_hand"),
                                                                     REGIONS.index("right_arm")]))
    assert len(rows) >= 1
    best = rows[np.argmin(gaps.gap[rows])]
    assert -0.05 < gaps.gap[best] < 0.0
    assert abs(np.linalg.norm(gaps.direction[best]) - 1.0) < 1e-6
    # Nothing of the left arm's own skin counts for the left hand.
    assert not np.any((gaps.probe == 0) & np.isin(gaps.region, [REGIONS.index("left_hand"), REGIONS.index("left_arm")]))


def test_the_stage_keeps_contacts_by_default_with_a_mesh_and_not_without():
    from live.body.body import Body
    from live.pipeline.stages import RetargetStage

    avatar = load_body("child_boy_9y")
    assert RetargetStage(avatar).contacts
    assert not RetargetStage(avatar, contacts="off").contacts
    cloud = Body(vertices=avatar.vertices, faces=np.zeros((0, 3), np.int32), rest_joints=avatar.rest_joints,
                 weights=avatar.weights, parents=avatar.parents, name="cloud")
    assert not RetargetStage(cloud).contacts
    with pytest.raises(UserInputError, match="mesh"):
        RetargetStage(cloud, contacts="on")


@needs_bvh
def test_eval_contacts_json_has_both_runs(capsys):
    from live.app.cli import main

    code = main(["eval", "contacts", "--motion", str(BVH / "daz_indian_04.bvh"), "--source-body", "adult_male_average",
                 "--target-body", "child_girl_6y", "--max-frames", "12", "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    for key in ("hand_contact_recall", "hand_contact_precision", "penetration_mean_mm", "penetration_max_mm",
                "mpjpe_mm", "wrist_bend_max_deg"):
        assert key in report and key in report["off"]
    assert report["frames"] == 12
    assert report["off"]["wrist_bend_max_deg"] < 1e-3  # the retargeter carries hands along their forearms


def test_wrist_bend_is_the_angle_of_the_wrists_local_rotation():
    from live.core.rotations import quat_from_axis_angle, quat_identity
    from live.evaluation.contacts import wrist_scores

    rotations = quat_identity((3, 22))
    rotations[1, JOINT_INDEX["left_wrist"]] = quat_from_axis_angle(np.array([0.0, 0.0, np.radians(30.0)]))
    rotations[2, JOINT_INDEX["left_elbow"]] = quat_from_axis_angle(np.array([np.radians(80.0), 0.0, 0.0]))
    scores = wrist_scores(rotations)
    assert scores["wrist_bend_max_deg"] == pytest.approx(30.0)
    assert scores["wrist_bend_mean_deg"] == pytest.approx(30.0 / 6)


def test_eval_contacts_refuses_a_missing_motion(capsys):
    from live.app.cli import main

    assert main(["eval", "contacts", "--motion", "no_such_clip.bvh"]) == 2
    assert "no such motion file" in capsys.readouterr().err


@needs_bvh
def test_contact_clips_put_the_performers_hands_on_its_hips_and_together():
    """The held-out walks made into contact clips: the performer's own skinned hands touch."""
    from live.evaluation.contact_clips import _clap_gap, _gaps, take_motion

    body = load_body("adult_male_average")
    hips = take_motion("cc_007_04.bvh", 0, 8, "hands-on-hips", body)
    assert np.abs(_gaps("hands-on-hips", body, np.asarray(hips.joints, np.float64))).max() < 0.005
    clap = take_motion("mb_08_04.bvh", 76, 8, "clapping", body)
    gaps = _gaps("clapping", body, np.asarray(clap.joints, np.float64))
    closed = _clap_gap(np.arange(8) / 30.0) == 0.0
    assert closed.any() and np.all(gaps[closed] < 0.01) and np.all(gaps[closed] > -0.02)


@needs_bvh
def test_clapping_hands_stay_clear_of_the_performers_own_face():
    """Hands follow their forearms: clapped too high, the fingers went into the chin and the
    face. The claps of the held-out take keep them clear of the head."""
    from live.body.skinning import lbs
    from live.evaluation.contact_clips import take_motion
    from live.evaluation.contacts import REGIONS, BodyRegions, contact_geometry
    from live.evaluation.retarget import _on_body
    from live.retarget.analytic import local_rotations_from_joints

    body = load_body("adult_male_average")
    clap = take_motion("mb_08_04.bvh", 0, 44, "clapping", body)
    root, joints = _on_body(clap, body.rest_joints)
    frames = np.r_[20:26, 34:44]  # two claps where the fingers reached the face
    pose = local_rotations_from_joints(joints[frames], body.rest_joints)
    verts = lbs(body.vertices, body.weights, body.rest_joints, pose, root[frames])
    gaps, _ = contact_geometry(BodyRegions.of(body), np.asarray(body.faces, np.int64), verts)
    assert gaps[:, :, list(REGIONS).index("head")].min() > 0.01


def test_an_avatar_without_skin_on_some_joints_still_keeps_contacts():
    """A VRM's skin often skips a spine segment: that part is never near, the rest works."""
    vrm = assets.shared_data_dir() / "avatars" / "godette_vrm0.vrm"
    if not vrm.is_file():
        pytest.skip("needs ../shared/data/avatars")
    from live.body.avatar import load_avatar
    from live.pipeline.stages import RetargetStage

    avatar = load_avatar(vrm)
    assert RetargetStage(avatar).contacts
    surface = body_surface(avatar)
    glob, pos = np.tile(np.eye(3), (22, 1, 1)), np.asarray(avatar.rest_joints, np.float64)
    assert np.all(measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003).gap > 0.03)  # T-pose: nothing touches


@needs_bvh
def test_the_rigid_broad_phase_never_drops_a_pair_the_skinned_one_measures():
    """measure's first test (probe spheres carried by their joints, no skinning) only skips
    frames where nothing is near: over a take with hands at the hips and hands far from the body
    it returns the same gaps as with that test made to pass always."""
    import live.retarget.contacts_surface as cs
    from live.evaluation.retarget import prepare_motion
    from live.retarget.retargeter import AnalyticRetargeter

    source, target = load_body("adult_male_average"), load_body("tall_heavy_male")
    surface = body_surface(target)
    motion = prepare_motion(BVH / "mb_49_11.bvh", 30.0)
    from live.evaluation.retarget import _on_body

    _, joints = _on_body(motion, source.rest_joints)
    rt = AnalyticRetargeter(source.rest_joints, target.rest_joints)
    skipped = 0
    for j in joints[::12][:40]:
        _, _, pos = rt.step(j)
        glob = rt.last_globals
        gated = measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003)
        slack, cs.SKIN_SLACK = cs.SKIN_SLACK, 10.0
        try:
            full = measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003)
        finally:
            cs.SKIN_SLACK = slack
        skipped += len(gated.gap) == 0 and len(full.gap) == 0
        assert np.array_equal(gated.probe, full.probe) and np.array_equal(gated.region, full.region)
        assert np.allclose(gated.gap, full.gap)
    assert 0 < skipped < 40  # some frames have nothing near, some do


def _heavy_avatar_posed(place_arms):
    """The heaviest avatar's surface, rest info and pose (globals (22, 3, 3), joints (22, 3)) with
    its arm joints where ``place_arms(pose)`` puts them in a copy of the rest joints."""
    from live.core.kinematics import forward_kinematics_matrices, local_matrices
    from live.retarget.analytic import RestInfo, solve_globals

    body = load_body("tall_heavy_male")
    rest = np.asarray(body.rest_joints, np.float64)
    info = RestInfo.of(rest)
    pose = rest.copy()
    place_arms(pose)
    glob = solve_globals(pose[None], info)[0][0]
    pos, glob = (a[0] for a in forward_kinematics_matrices(local_matrices(glob)[None], pose[None, 0], info.offsets))
    return body_surface(body), info, glob, pos


def _heavy_avatar_arms_hanging():
    """The heavy avatar with its arms down beside the body, clear of it, and a performer touching
    nothing: (surface, info, glob, pos, source contacts)."""
    from live.retarget.contacts_self import SourceContacts

    def hanging(pose):
        j = JOINT_INDEX
        for side, sign in (("left", 1.0), ("right", -1.0)):
            pose[j[f"{side}_elbow"]] = pose[j[f"{side}_shoulder"]] + [0.12 * sign, -0.28, 0.0]
            pose[j[f"{side}_wrist"]] = pose[j[f"{side}_elbow"]] + [0.06 * sign, -0.25, 0.05]

    surface, info, glob, pos = _heavy_avatar_posed(hanging)
    nothing = np.zeros((len(PROBES), len(REGIONS)))
    return surface, info, glob, pos, SourceContacts(gap=nothing + 1.0, contact=nothing > 0, weight=nothing)


def _arms_turned(glob: np.ndarray, pos: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(globals, joints) of a pose with the arms turned by a correction state (2, 4)."""
    from live.core.kinematics import local_matrices
    from live.retarget.contacts_keep import ARMS, ContactKeeper, _Posed

    g, p = glob.copy(), pos.copy()
    ContactKeeper._apply(g, local_matrices(glob), p, [_Posed(glob, pos, arm) for arm in ARMS], state)
    return g, p


def _left_arm_depth(surface, glob: np.ndarray, pos: np.ndarray) -> float:
    """How deep (m, 0 when outside) the left hand and forearm are inside the body, as measured."""
    from live.retarget.contacts_keep import _ARM_PROBES

    gaps = measure(surface, glob, pos, _ARM_PROBES[0], 0.15, 0.003, 0.15)
    return -gaps.gap.min() if len(gaps.gap) else 0.0


def test_a_hand_holding_the_other_forearm_takes_it_along_out_of_the_body():
    """Both arms are one system: the left hand holds the right forearm, both sunk into the heavy
    avatar's belly; pushed out, the hand stays on the forearm (on the avatar's own surface)."""
    from live.core.kinematics import local_matrices
    from live.retarget.contacts_keep import ContactKeeper
    from live.retarget.contacts_self import SourceContacts

    def folded(pose):  # forearms across the belly: elbows by the sides, wrists in front of the navel
        j = JOINT_INDEX
        front = pose[j["spine1"]] + [0.0, 0.02, 0.10]
        for side, sign in (("left", 1.0), ("right", -1.0)):
            pose[j[f"{side}_elbow"]] = pose[j[f"{side}_shoulder"]] + [0.06 * sign, -0.28, 0.05]
            pose[j[f"{side}_wrist"]] = front + [0.02 * sign, 0.0, 0.0]

    surface, info, glob, pos = _heavy_avatar_posed(folded)
    gap = np.full((len(PROBES), len(REGIONS)), 1.0)
    weight = np.zeros_like(gap)
    hold = ([p.name for p in PROBES].index("left_hand"), REGIONS.index("right_arm"))
    gap[hold], weight[hold] = 0.0, 1.0
    source = SourceContacts(gap=gap, contact=weight > 0, weight=weight)
    torso = REGIONS.index("torso")
    before = measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003)
    assert before.gap[(before.probe == hold[0]) & (before.region == torso)].min() < -0.01
    keeper = ContactKeeper(info.offsets)
    for _ in range(6):  # the same pose held a few frames
        g, p = glob.copy(), pos.copy()
        keeper(surface, g, local_matrices(glob), p, source, 1 / 30)
    after = measure(surface, g, p, ALL_PROBES, 0.15, 0.003, 0.15)
    assert after.gap[(after.probe == hold[0]) & (after.region == torso)].min() > -0.003
    held = after.gap[(after.probe == hold[0]) & (after.region == hold[1])]
    assert len(held) and held.min() < 0.012


def test_the_tuning_takes_share_no_subject_clip_or_body_with_the_held_out_ones():
    from live.evaluation.contact_clips import CONTACT_TAKES, TUNING_TAKES
    from live.evaluation.contacts import CONTACT_AVATARS, CONTACT_PERFORMER, TUNING_AVATARS, TUNING_PERFORMER
    from sim.skeleton_data import list_clips, split_clips

    training = {c.file for c in split_clips(list_clips(assets.bvh_dir()), "train")}
    assert {t[0] for t in TUNING_TAKES} <= training  # on disk, and no held-out subject
    assert not {t[0] for t in TUNING_TAKES} & {t[0] for t in CONTACT_TAKES}
    assert not ({TUNING_PERFORMER, *TUNING_AVATARS} & {CONTACT_PERFORMER, *CONTACT_AVATARS})


def test_a_carried_correction_that_drags_an_arm_into_the_body_is_dropped():
    """An arm corrected on the frames before, now where that correction would hold it deep inside
    the belly while the retargeter's own pose is outside: the arm starts again from that pose
    rather than being rate-limited out of the body over many frames."""
    from live.core.kinematics import local_matrices
    from live.retarget.contacts_keep import _ARM_PROBES, ARMS, ContactKeeper, _Posed

    surface, info, glob, pos, source = _heavy_avatar_arms_hanging()
    clear = measure(surface, glob, pos, ALL_PROBES, 0.05, 0.003)
    assert not len(clear.gap) or clear.gap.min() > 0.0

    def depth_of_left(state):
        g, p = glob.copy(), pos.copy()
        ContactKeeper._apply(g, local_matrices(glob), p, [_Posed(glob, pos, arm) for arm in ARMS], state)
        gaps = measure(surface, g, p, _ARM_PROBES[0], 0.15, 0.003, 0.15)
        return -gaps.gap.min() if len(gaps.gap) else 0.0

    # A carried correction that swings the left arm in across the belly, 5 cm or more deep.
    deep = next(s for s in (np.array([[0.0, 0.0, -a, 0.0], [0.0] * 4]) for a in np.linspace(0.2, 1.4, 25))
                if depth_of_left(s) > 0.05)
    keeper = ContactKeeper(info.offsets)
    keeper(surface, glob.copy(), local_matrices(glob), pos.copy(), source, 1 / 30)  # a first frame: nothing near
    keeper.state = deep.copy()
    keeper.state[:, :3] = deep[:, :3] @ glob[0]  # kept in the pelvis frame
    g, p = glob.copy(), pos.copy()
    keeper(surface, g, local_matrices(glob), p, source, 1 / 30)
    after = measure(surface, g, p, _ARM_PROBES[0], 0.15, 0.003, 0.15)
    assert not len(after.gap) or after.gap.min() > -0.005


@needs_bvh
def test_the_measure_follows_the_skinned_mesh_where_a_bent_spine_moves_the_belly():
    """Bent over washing, copied onto the heaviest training avatar: the runtime's gaps of hands
    and forearms to the torso against the exact distance to the skinned skin (the evaluation's
    cut: faces of torso-dominant vertices, open edges outside). Where skinning moves the skin far
    from where a part's joint alone carries it, the rigid grids alone were off by more than 5 cm
    on a tenth of these rows (4 mm with the skinned mesh)."""
    from live.body.skinning import lbs
    from live.evaluation.contact_clips import TUNING_TAKES, take_motion
    from live.evaluation.contacts import TUNING_PERFORMER, skin_distances
    from live.evaluation.retarget import make_retargeter, source_skeletons
    from live.retarget.contacts_surface import border_vertices

    performer, avatar = load_body(TUNING_PERFORMER), load_body("heavy_male")
    motion = take_motion(*next(t for t in TUNING_TAKES if t[0] == "cc_002_10.bvh"), performer, BVH)
    joints, source_rest, _ = source_skeletons(motion, performer, "skeleton")
    retargeter = make_retargeter("analytic", source_rest, avatar.rest_joints, 30.0)
    surface = body_surface(avatar)
    faces = np.asarray(avatar.faces, np.int64)
    region_of = surface.model.vertex_region  # by each vertex's heaviest joint
    skin = faces[skin_faces(faces, region_of == REGIONS.index("torso"))]
    border = border_vertices(skin, len(region_of))
    errors = []
    for t, frame in enumerate(joints):
        root, quats, pos = retargeter.step(frame)
        if t % 3:
            continue
        gaps = measure(surface, np.array(retargeter.last_globals), np.asarray(pos, np.float64), ALL_PROBES, 0.03, 0.003)
        rows = np.flatnonzero((gaps.region == REGIONS.index("torso")) & (gaps.gap < 0.03))
        if not len(rows):
            continue
        v = lbs(avatar.vertices, avatar.weights, avatar.rest_joints, np.asarray(quats), np.asarray(root))[0]
        v = v.astype(np.float64)
        normals = vertex_normals(v, faces)
        for row in rows:
            pts = v[surface.model.probes[gaps.probe[row]]]
            errors.append(gaps.gap[row] - skin_distances(v, normals, skin, pts, border).min())
    errors = np.abs(np.array(errors))
    assert len(errors) > 50
    assert np.percentile(errors, 90) < 0.01 and np.median(errors) < 0.002


@needs_bvh
def test_a_hand_on_the_other_forearm_by_its_wrist_reads_as_near():
    """Salsa copied onto the slimmest training avatar, one hand on the other forearm by its wrist
    (1 mm from its skin). Each part's grid holds only its own region's skin: the forearm's grid
    overlapped the hand's skin there, its samples counted for the hand, and the arm's row read
    36 mm (a contact lost, the keeper then pulling the hand away)."""
    from live.body.skinning import lbs
    from live.evaluation.contact_clips import TUNING_TAKES, take_motion
    from live.evaluation.contacts import TUNING_PERFORMER, skin_distances
    from live.evaluation.retarget import make_retargeter, source_skeletons
    from live.retarget.contacts_surface import border_vertices

    performer, avatar = load_body(TUNING_PERFORMER), load_body("child_boy_4y")
    motion = take_motion(*next(t for t in TUNING_TAKES if t[0] == "daz_salsa_16.bvh"), performer, BVH)
    joints, source_rest, _ = source_skeletons(motion, performer, "skeleton")
    retargeter = make_retargeter("analytic", source_rest, avatar.rest_joints, 30.0)
    for frame in joints[:153]:
        root, quats, pos = retargeter.step(frame)
    surface = body_surface(avatar)
    gaps = measure(surface, np.array(retargeter.last_globals), np.asarray(pos, np.float64), ALL_PROBES, 0.1, 0.003, 0.1)
    faces = np.asarray(avatar.faces, np.int64)
    region_of = surface.model.vertex_region
    skin = faces[skin_faces(faces, region_of == REGIONS.index("right_arm"))]
    v = lbs(avatar.vertices, avatar.weights, avatar.rest_joints, np.asarray(quats), np.asarray(root))[0].astype(np.float64)
    hand = [p.name for p in PROBES].index("left_hand")
    exact = skin_distances(v, vertex_normals(v, faces), skin, v[surface.model.probes[hand]],
                           border_vertices(skin, len(region_of))).min()
    row = (gaps.probe == hand) & (gaps.region == REGIONS.index("right_arm"))
    assert exact < 0.005
    assert row.any() and gaps.gap[row].min() < 0.015


def test_a_contact_of_an_estimated_performer_is_kept_touching():
    """With ``touch`` (ESTIMATED: a performer known by an estimated skeleton on a fitted
    template) a held contact's bounds are the margin, whatever gap the estimate measured; by
    default they are the performer's gap."""
    from live.retarget.contacts_keep import ContactKeeper
    from live.retarget.contacts_self import ESTIMATED, SourceContacts
    from live.retarget.contacts_surface import Gaps

    hand, torso = [p.name for p in PROBES].index("left_hand"), REGIONS.index("torso")
    gap = np.full((len(PROBES), len(REGIONS)), 1.0)
    weight = np.zeros_like(gap)
    gap[hand, torso], weight[hand, torso] = 0.022, 1.0
    source = SourceContacts(gap=gap, contact=weight > 0, weight=weight)
    row = Gaps(np.array([hand]), np.array([torso]), np.array([0.05]), np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3)))
    offsets = np.zeros((22, 3))
    lower, upper, _ = ContactKeeper(offsets, ESTIMATED).bounds(row, source)
    assert lower[0] == upper[0] == ESTIMATED.margin
    lower, upper, _ = ContactKeeper(offsets).bounds(row, source)
    assert lower[0] == upper[0] == pytest.approx(0.022)
    assert ESTIMATED.on > ContactSettings().on and ESTIMATED.off > ContactSettings().off


def test_the_stage_reads_the_depth_stages_skeleton_as_an_estimate():
    """Behind the depth stage the performer's contacts are read with ESTIMATED; from the truth
    (or, set by ``replay --only imu|fused``, a suit's skeleton) with the exact settings."""
    from live.pipeline.stages import RetargetStage
    from live.retarget.contacts_self import ESTIMATED

    avatar = load_body("child_girl_6y")
    rest = np.asarray(load_body("adult_male_average").rest_joints, np.float64)
    depth = RetargetStage(avatar)
    truth = RetargetStage(avatar, use_truth=True)
    suit = RetargetStage(avatar, estimated=False)
    assert depth._make(rest).settings == ESTIMATED
    assert truth._make(rest).settings == ContactSettings()
    assert suit._make(rest).settings == ContactSettings()


@pytest.mark.parametrize("outward", [True, False])
def test_an_arm_holding_nothing_lets_its_correction_go_unless_that_sinks_it(outward):
    """(Exact skeletons' settings: ``let_go``.) A correction carried into frames where the performer touches nothing: with nothing in the
    way (the arm turned out, away from the heavy avatar's body) it is let go at ``release_s`` (within
    the rate limit), where the damped steps alone stall part of the way; where letting it go would sink the arm (turned in, the
    correction holding it out of the belly), the arm stays out, frame after frame, without
    bouncing."""
    from live.core.kinematics import local_matrices
    from live.retarget.contacts_keep import ARMS, PUSH_DEPTH, ContactKeeper

    surface, info, glob, pos, source = _heavy_avatar_arms_hanging()

    def swung(state):  # the pose with the left arm turned by state
        return _arms_turned(glob, pos, state)

    def depth_of_left(g, p):
        return _left_arm_depth(surface, g, p)

    if outward:  # the retargeter's arm hangs clear; the correction holds it turned out
        base, turn = (glob, pos), np.array([[0.0, 0.0, 0.5, 0.0], [0.0] * 4])
    else:  # the retargeter's arm is 3 cm inside the belly; the correction holds it out
        base = next(sw for sw in (swung(np.array([[0.0, 0.0, -a, 0.0], [0.0] * 4]))
                                  for a in np.linspace(0.2, 1.4, 49)) if depth_of_left(*sw) > 0.03)
        turn = None

    def run(release: bool, frames: int = 12):
        keeper = ContactKeeper(info.offsets, ContactSettings(let_go=release))
        if turn is not None:
            keeper(surface, base[0].copy(), local_matrices(base[0]), base[1].copy(), source, 1 / 30)
            keeper.state = turn.copy()
            keeper.state[:, :3] = turn[:, :3] @ base[0][0]  # kept in the pelvis frame
        wrists, depths, sizes = [], [], []
        for _ in range(frames):
            g, p = base[0].copy(), base[1].copy()
            keeper(surface, g, local_matrices(base[0]), p, source, 1 / 30)
            wrists.append(p[ARMS[0].wrist].copy())
            depths.append(depth_of_left(g, p))
            sizes.append(float(np.abs(keeper.state[0]).max()))
        return np.array(wrists), np.array(depths), np.array(sizes)

    wrists, depths, let_go = run(True)
    _, _, stepped = run(False)
    if outward:
        decay = np.exp(-(1 / 30) / ContactKeeper(info.offsets).release_s)
        assert let_go[-1] < 0.5 * decay ** 11  # let go at release_s (and the steps' pull on top)
        assert stepped[-1] > 3 * let_go[-1]  # the damped steps alone stall part of the way
    else:
        assert depths[2:].max() < PUSH_DEPTH + 0.002  # held out of the belly once pushed
        speed = np.linalg.norm(np.diff(wrists[2:], axis=0), axis=1)
        assert speed.max() < 0.003  # still: no letting in and pushing out again
        assert np.allclose(let_go[2:], stepped[2:], atol=1e-9)  # letting go would sink it: not done


def test_a_strike_into_the_belly_is_pushed_out_on_the_frame_it_lands():
    """The left arm swings from beside the body to 9 cm inside the heavy belly in one frame (a
    strike): the damped steps alone leave it 2 cm inside; the push-out after them takes it out to
    within PUSH_DEPTH on that frame, and on the next, the arm still there, it stays out."""
    from live.core.kinematics import local_matrices
    from live.retarget import contacts_keep
    from live.retarget.contacts_keep import PUSH_DEPTH, ContactKeeper

    surface, info, glob, pos, source = _heavy_avatar_arms_hanging()

    def swung(state):  # the retargeter's own pose with the left arm turned by state
        return _arms_turned(glob, pos, state)

    def depth_of_left(g, p):
        return _left_arm_depth(surface, g, p)

    strike = next(sw for sw in (swung(np.array([[0.0, 0.0, -a, 0.0], [0.0] * 4])) for a in np.linspace(0.2, 1.4, 25))
                  if depth_of_left(*sw) > 0.09)

    def run(frames):
        keeper = ContactKeeper(info.offsets)
        keeper(surface, glob.copy(), local_matrices(glob), pos.copy(), source, 1 / 30)  # clear: nothing near
        depths = []
        for _ in range(frames):
            g, p = strike[0].copy(), strike[1].copy()
            keeper(surface, g, local_matrices(strike[0]), p, source, 1 / 30)
            depths.append(depth_of_left(g, p))
        return depths

    with_push = run(2)
    assert max(with_push) < PUSH_DEPTH + 0.002
    original = contacts_keep.PUSH_STEPS
    contacts_keep.PUSH_STEPS = 0
    try:
        without = run(1)
    finally:
        contacts_keep.PUSH_STEPS = original
    assert without[0] > 0.01


def test_the_two_rows_between_the_hands_point_one_way():
    """Hands inside each other: each hand's distance field points to its own nearest skin, and
    the two rows (left hand to right hand, and back) asked the arms to go two ways at once. They
    are made opposite, along the difference of their directions; a row of no pair is left as it
    was, and two rows asking the same way are set apart along their points."""
    from live.retarget.contacts_keep import HAND_ROWS, _hands_one_way
    from live.retarget.contacts_surface import Gaps

    (pa, ra), (pb, rb) = HAND_ROWS
    d_a, d_b = np.array([0.44, 0.58, -0.68]), np.array([0.93, 0.12, 0.34])
    d_a, d_b = d_a / np.linalg.norm(d_a), d_b / np.linalg.norm(d_b)
    torso = np.array([0.0, 0.0, 1.0])
    points = np.array([[0.0, 1.0, 0.2], [0.0, 1.02, 0.2], [0.0, 1.0, 0.2]])
    gaps = Gaps(probe=np.array([pa, pb, pa]), region=np.array([ra, rb, REGIONS.index("torso")]),
                gap=np.array([-0.010, -0.011, 0.02]), direction=np.array([d_a, d_b, torso]), point=points)
    out = _hands_one_way(gaps)
    way = (d_a - d_b) / np.linalg.norm(d_a - d_b)
    assert np.allclose(out.direction[0], way) and np.allclose(out.direction[1], -way)
    assert np.allclose(out.direction[2], torso)
    assert np.array_equal(out.gap, gaps.gap) and np.array_equal(out.point, gaps.point)
    assert np.array_equal(gaps.direction[0], d_a)  # the measured gaps are not changed in place
    same = _hands_one_way(Gaps(gaps.probe, gaps.region, gaps.gap, np.array([torso, torso, torso]), points))
    assert np.allclose(same.direction[0], [0.0, -1.0, 0.0]) and np.allclose(same.direction[1], [0.0, 1.0, 0.0])
