"""Self-contacts and interpenetration of retargeting: ``livecap eval contacts``.

A motion is put on the performer's body and retargeted onto the avatar as ``livecap eval retarget`` does (from the exact
skeleton, or through the virtual camera and the skeleton stage), once with the self-contact
correction (live/retarget/contacts_retargeter.py) and once without. Every mesh is skinned and
measured exactly, frame by frame (open3d closest points on the posed skin, not the runtime's
grids):

* **hand contacts**: for each hand and each region (the other hand, the other arm, head and
  neck, torso, legs) the signed distance from the hand's skin to the region's. A pair touches when within
  ``TOUCH`` (1 cm, sinking in included). Recall: of the performer's touching pairs, the share
  the avatar keeps within ``KEEP`` (2 cm); precision: of the avatar's touching pairs, the share
  within ``KEEP`` on the performer.
* **penetration**: per frame and arm, the deepest point of the hand and forearm skin inside the
  torso, head, legs or the other arm (hand, forearm, upper arm) (mm). Mean over the (frame, arm) pairs that sink in by at
  least ``SINK`` (1 mm), max over all; ``penetrating_share`` says how many pairs that is.
* **joints**: MPJPE, PA-MPJPE, Acc, PA-Acc against the rotation copy on the avatar, as in
  ``livecap eval retarget`` (live/evaluation/retarget.py).

The performer's contacts are those of its true body posed by its true 22-joint skeleton. A
skeleton has no hand rotation: hands follow their forearms, on the performer as on the avatar
(with the motion's own wrist rotations, which no skeleton-driven retargeter receives, a walk's
swinging hands brush the thighs where the skeleton's pass 3-5 cm from them). The surface the
correction sees: the true body from exact skeletons, or, from depth, a template body fitted to
the estimated skeleton (what a live performer gets).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX

TOUCH = 0.010
KEEP = 0.020
SINK = 0.001
#: The gap recorded for a hand far from a region (m).
FAR = 1.0
#: Regions a hand may touch, by the joints whose dominant-weight vertices make them.
REGIONS = {"hand": None, "arm": None, "head": ("neck", "head"),
           "torso": ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar"),
           "legs": ("left_hip", "right_hip", "left_knee", "right_knee")}
SIDES = ("left", "right")


@dataclass(frozen=True)
class BodyRegions:
    """A body's skin cut by dominant weight: vertices of each hand and forearm, faces of each
    region (a face belongs where two of its vertices do: the regions' skins, in REGIONS' order,
    the hand's being the left then the right) and their open edges' vertices."""

    hand: tuple[np.ndarray, ...]
    forearm: tuple[np.ndarray, ...]
    skins: dict[str, np.ndarray]
    borders: dict[str, np.ndarray]

    @classmethod
    def of(cls, body) -> BodyRegions:
        from live.retarget.contacts_surface import border_vertices, skin_faces

        dominant = np.asarray(body.weights).argmax(1)
        faces = np.asarray(body.faces, np.int64)

        def members(names) -> np.ndarray:
            return np.isin(dominant, [JOINT_INDEX[n] for n in names])

        groups = {f"{s}_hand": (f"{s}_wrist",) for s in SIDES}
        groups.update({f"{s}_arm": (f"{s}_shoulder", f"{s}_elbow") for s in SIDES})
        groups.update({k: v for k, v in REGIONS.items() if v is not None})
        skins = {k: faces[skin_faces(faces, members(v))] for k, v in groups.items()}
        return cls(hand=tuple(np.flatnonzero(members((f"{s}_wrist",))) for s in SIDES),
                   forearm=tuple(np.flatnonzero(members((f"{s}_elbow",))) for s in SIDES),
                   skins=skins, borders={k: border_vertices(f, len(dominant)) for k, f in skins.items()})


def skin_distances(vertices: np.ndarray, normals: np.ndarray, skin: np.ndarray, points: np.ndarray,
                   border: np.ndarray) -> np.ndarray:
    """Exact signed distances (Q,) of points (Q, 3) to the skin made of faces ``skin`` of a posed
    mesh (vertices, unit vertex normals; ``border``: the skin's open-edge vertices), negative
    inside only where the skin also winds about the point: a fold of the skinned mesh turns the
    closest face's normal inward far from any real penetration."""
    from live.retarget.contacts_surface import signed_distances, winding_numbers

    d = signed_distances(vertices, normals, skin, points, border)[0]
    inside = np.flatnonzero(d < 0.0)
    if len(inside):
        d[inside[winding_numbers(vertices, skin, points[inside]) < 0.3]] *= -1.0
    return d


def contact_geometry(regions: BodyRegions, faces: np.ndarray, vertices: np.ndarray, progress=None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of posed vertices (T, V, 3): hand gaps (T, 2 hands, 4 regions as REGIONS, m)
    and the arms' deepest penetration (T, 2 arms, m, >= 0)."""
    from live.retarget.contacts_surface import vertex_normals

    t_count = len(vertices)
    gaps = np.full((t_count, 2, len(REGIONS)), FAR)
    depth = np.zeros((t_count, 2))
    arms = [np.concatenate([regions.hand[a], regions.forearm[a]]) for a in range(2)]
    hands = [len(h) for h in regions.hand]
    for t in range(t_count):
        v = np.asarray(vertices[t], np.float64)
        normals = None
        worst = np.zeros(2)
        boxes = {k: (v[f.ravel()].min(0) - KEEP, v[f.ravel()].max(0) + KEEP) for k, f in regions.skins.items()}
        for r, name in enumerate(REGIONS):
            for a in range(2):
                skin_name = f"{SIDES[1 - a]}_{name}" if name in ("hand", "arm") else name
                skin = regions.skins[skin_name]
                # Only points near the region's box can touch or sink in: the others stay FAR.
                lo, hi = boxes[skin_name]
                pts = v[arms[a]]
                near = np.all((pts > lo) & (pts < hi), axis=1)
                if not near.any():
                    continue
                if normals is None:
                    normals = vertex_normals(v, faces)
                d = np.full(len(pts), FAR)
                d[near] = skin_distances(v, normals, skin, pts[near], regions.borders[skin_name])
                gaps[t, a, r] = d[: hands[a]].min()
                worst[a] = min(worst[a], float(d.min()))
        depth[t] = -worst
        if progress is not None:
            progress(t + 1, t_count)
    return gaps, depth


def contact_scores(source_gaps: np.ndarray, avatar_gaps: np.ndarray, depth: np.ndarray) -> dict[str, Any]:
    """Recall, precision (nan when there is nothing to count) and penetration of one avatar run."""
    src_touch, ava_touch = source_gaps <= TOUCH, avatar_gaps <= TOUCH
    kept = (avatar_gaps <= KEEP) & src_touch
    true = (source_gaps <= KEEP) & ava_touch
    sinking = depth >= SINK
    return {
        "hand_contact_recall": float(kept.sum() / src_touch.sum()) if src_touch.any() else float("nan"),
        "hand_contact_precision": float(true.sum() / ava_touch.sum()) if ava_touch.any() else float("nan"),
        "penetration_mean_mm": float(1000 * depth[sinking].mean()) if sinking.any() else 0.0,
        "penetration_max_mm": float(1000 * depth.max()) if depth.size else 0.0,
        "penetrating_share": float(sinking.mean()) if depth.size else 0.0,
        "penetrating_pairs": int(sinking.sum()),
        "kept_hand_contacts": int(kept.sum()),
        "true_avatar_contacts": int(true.sum()),
        "source_hand_contacts": int(src_touch.sum()),
        "avatar_hand_contacts": int(ava_touch.sum()),
    }


def joint_scores(joints: np.ndarray, gt_joints: np.ndarray) -> dict[str, float]:
    from live.core.metrics import acceleration_error, mpjpe, pa_acceleration_error, pa_mpjpe

    return {"mpjpe_mm": 1000 * mpjpe(joints, gt_joints), "pa_mpjpe_mm": 1000 * pa_mpjpe(joints, gt_joints),
            "acc_mm_per_frame2": 1000 * acceleration_error(joints, gt_joints),
            "pa_acc_mm_per_frame2": 1000 * pa_acceleration_error(joints, gt_joints)}


def wrist_scores(rotations: np.ndarray) -> dict[str, float]:
    """How far the avatar's hands bend at the wrist (degrees, the wrists' local rotations of
    rotations T x 22 x 4), mean and max over frames and hands. A skeleton gives no hand
    orientation and the retargeters carry hands along their forearms (no bend); the correction
    turns an arm and keeps its hand's world orientation, so the wrist bends by what the forearm
    turned (live/retarget/contacts_keep.py): what a viewer sees of it at the hands."""
    from live.core.rotations import quat_angle

    bend = np.degrees(quat_angle(rotations[:, [JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]]]))
    return {"wrist_bend_mean_deg": float(bend.mean()), "wrist_bend_max_deg": float(bend.max())}


def run_retargeter(rt, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(root T x 3, rotations T x 22 x 4, joints T x 22 x 3) of source joints through ``rt``."""
    return tuple(np.stack(x) for x in zip(*(rt.step(j) for j in joints)))  # type: ignore[return-value]


def evaluate_contacts(motion, source_body, target_body, from_: str = "skeleton", retarget: str = "analytic", *,
                      fps: float = 30.0, max_frames: int | None = None, camera: str = "oak-d", seed: int = 0,
                      lag: int = 0, settings=None, progress=None, skeletons=None, per_frame: bool = False
                      ) -> dict[str, Any]:
    """The correction on and off for one motion from a source body to a target body.

    motion: a Motion or a BVH path (prepared as ``livecap eval retarget`` does); bodies: Body or
    a spec. Returns the corrected figures at the top level (``hand_contact_recall``,
    ``hand_contact_precision``, ``penetration_mean_mm``, ``penetration_max_mm``, ``mpjpe_mm``,
    and more), the same without the correction under ``"off"``, the performer's own penetration
    under ``"source"``, and the run's names and settings. skeletons: what the retargeter sees, as
    ``source_skeletons`` returns it for this motion and source (reused across avatars). per_frame:
    also the frame-by-frame arrays under ``"per_frame"`` (gaps, depths, joints; not JSON), to
    find which frames and which arm a figure comes from."""
    from live.body.library import load_body
    from live.body.skinning import lbs
    from live.evaluation.retarget import _on_body, check_options, make_retargeter, prepare_motion, source_skeletons
    from live.motion.rig_mapping import load_motion
    from live.retarget.analytic import local_rotations_from_joints
    from live.retarget.contacts_retargeter import ContactRetargeter, PerformerSurfaces
    from live.retarget.contacts_self import settings_for
    from live.retarget.contacts_surface import body_surface

    check_options(from_, retarget)
    if isinstance(motion, (str, Path)):
        motion = load_motion(motion)
    motion = prepare_motion(motion, fps, max_frames)
    src = source_body if hasattr(source_body, "rest_joints") else load_body(source_body)
    tgt = target_body if hasattr(target_body, "rest_joints") else load_body(target_body)
    if len(tgt.faces) == 0 or len(src.faces) == 0:
        raise UserInputError("contacts are measured on meshes: both bodies need faces")
    if skeletons is None:
        skeletons = source_skeletons(motion, src, from_, camera=camera, seed=seed, lag=lag) \
            if from_ == "depth" else source_skeletons(motion, src, from_)
    joints, src_rest, found = skeletons
    gt_root, gt_joints = _on_body(motion, tgt.rest_joints)
    src_root, src_true = _on_body(motion, src.rest_joints)
    performer = body_surface(src) if from_ == "skeleton" else PerformerSurfaces()
    if settings is None:  # as the retarget stage reads a skeleton of this source
        settings = settings_for(from_ == "depth")
    runs = {"off": run_retargeter(make_retargeter(retarget, src_rest, tgt.rest_joints, fps), joints)}
    keeper = ContactRetargeter(make_retargeter(retarget, src_rest, tgt.rest_joints, fps), body_surface(tgt),
                               tgt.rest_joints, src_rest, performer, fps=fps, settings=settings)
    runs["on"] = run_retargeter(keeper, joints)
    src_regions, tgt_regions = BodyRegions.of(src), BodyRegions.of(tgt)
    # The performer as its skeleton shows it: the true joints' rotations, hands along the forearms.
    src_pose = local_rotations_from_joints(src_true, src.rest_joints)
    src_verts = lbs(src.vertices, src.weights, src.rest_joints, src_pose, src_root)
    src_gaps, src_depth = contact_geometry(src_regions, np.asarray(src.faces, np.int64), src_verts, progress)
    out: dict[str, Any] = {}
    frames: dict[str, Any] = {"source_gaps": src_gaps, "source_depth": src_depth, "gt_joints": gt_joints}
    for name, (root, rot, pred) in runs.items():
        verts = lbs(tgt.vertices, tgt.weights, tgt.rest_joints, rot, root)
        gaps, depth = contact_geometry(tgt_regions, np.asarray(tgt.faces, np.int64), verts, progress)
        scores = contact_scores(src_gaps, gaps, depth)
        scores.update(joint_scores(pred, gt_joints))
        scores.update(wrist_scores(rot))
        out[name] = scores
        frames[name] = {"gaps": gaps, "depth": depth, "joints": pred}
    result = dict(out["on"])
    result.update(off=out["off"], source={"penetration_mean_mm": contact_scores(src_gaps, src_gaps, src_depth)
                                          ["penetration_mean_mm"], "penetration_max_mm": float(1000 * src_depth.max())},
                  frames=int(motion.num_frames), fps=float(fps), motion=motion.name,
                  source_body=getattr(src, "name", "source"), target_body=getattr(tgt, "name", "target"),
                  retarget=retarget, found=float(found.mean()), lag=lag, **{"from": from_},
                  corrected_frames=int(keeper.counters["frames_corrected"]))
    if per_frame:
        result["per_frame"] = frames
    return result


_COLUMNS = (("hand_contact_recall", "recall", "{:.1%}"), ("hand_contact_precision", "precision", "{:.1%}"),
            ("penetration_mean_mm", "pen. mean mm", "{:.1f}"), ("penetration_max_mm", "pen. max mm", "{:.1f}"),
            ("penetrating_share", "sinking", "{:.1%}"), ("mpjpe_mm", "MPJPE mm", "{:.1f}"),
            ("pa_mpjpe_mm", "PA-MPJPE mm", "{:.1f}"), ("acc_mm_per_frame2", "Acc", "{:.2f}"),
            ("wrist_bend_max_deg", "wrist bend max deg", "{:.0f}"))


def _fmt(value, pattern: str) -> str:
    return "-" if value is None or (isinstance(value, float) and np.isnan(value)) else pattern.format(value)


def format_report(results: dict[str, Any] | list[dict[str, Any]]) -> str:
    """A Markdown table: per result, a row with the correction and one without."""
    rows = [results] if isinstance(results, dict) else list(results)
    head = "| motion | source -> target | from | contacts | " + " | ".join(c[1] for c in _COLUMNS) + " |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        for label, figures in (("on", r), ("off", r["off"])):
            cells = " | ".join(_fmt(figures.get(k), p) for k, p in ((c[0], c[2]) for c in _COLUMNS))
            lines.append(f"| {r['motion']} | {r['source_body']} -> {r['target_body']} | {r['from']} | {label} | {cells} |")
    lines.append("")
    lines.append(f"Hand contacts: touching within {TOUCH * 100:g} cm, kept within {KEEP * 100:g} cm; penetration of "
                 f"hands and forearms, mean over the (frame, arm) pairs sinking in by {SINK * 1000:g} mm or more; "
                 "Acc in mm/frame^2.")
    return "\n".join(lines)


#: The slimmest child and the heaviest adult of the body library; the performer, a held-out body.
CONTACT_AVATARS = ("child_girl_6y", "tall_heavy_male")
CONTACT_PERFORMER = "adult_male_average"
#: The tuning runs' bodies (TUNING_TAKES): another child and another heavy adult, a training performer.
TUNING_AVATARS = ("child_boy_4y", "heavy_male")
TUNING_PERFORMER = "middle_aged_male"


def contact_table(from_: str = "skeleton", *, takes=None, avatars=CONTACT_AVATARS,
                  performer: str = CONTACT_PERFORMER, progress=None) -> list[dict[str, Any]]:
    """Every take (default live.evaluation.contact_clips.CONTACT_TAKES) onto every avatar, the
    correction on and off (one result each, as ``evaluate_contacts``), and a last row pooling
    them (``motion``: "all")."""
    from live.body.library import load_body
    from live.evaluation.contact_clips import CONTACT_TAKES, take_motion
    from live.evaluation.retarget import source_skeletons

    takes = CONTACT_TAKES if takes is None else takes
    src = load_body(performer)
    rows = []
    for k, (clip, start, frames, kind) in enumerate(takes):
        motion = take_motion(clip, start, frames, kind, src)
        skeletons = source_skeletons(motion, src, from_, seed=k) if from_ == "depth" \
            else source_skeletons(motion, src, from_)
        for avatar in avatars:
            rows.append(evaluate_contacts(motion, src, load_body(avatar), from_, skeletons=skeletons))
            if progress is not None:
                progress(f"{motion.name} -> {avatar}")
    rows.append(pooled(rows))
    return rows


def pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One result for several: recall and precision over all their contacts, penetration mean
    over all sinking (frame, arm) pairs, max of the maxima, joint metrics averaged over frames."""
    def pool(runs: list[dict]) -> dict[str, float]:
        frames = np.array([r["frames"] for r in rows], float)
        src_c = sum(r["source_hand_contacts"] for r in runs)
        ava_c = sum(r["avatar_hand_contacts"] for r in runs)
        sinking = sum(r["penetrating_pairs"] for r in runs)
        out = {"hand_contact_recall": sum(r["kept_hand_contacts"] for r in runs) / src_c if src_c else float("nan"),
               "hand_contact_precision": sum(r["true_avatar_contacts"] for r in runs) / ava_c if ava_c else float("nan"),
               "penetration_mean_mm": sum(r["penetration_mean_mm"] * r["penetrating_pairs"] for r in runs) / sinking
               if sinking else 0.0,
               "penetration_max_mm": max(r["penetration_max_mm"] for r in runs),
               "penetrating_share": sinking / float(2 * frames.sum()),
               "source_hand_contacts": src_c, "avatar_hand_contacts": ava_c, "penetrating_pairs": sinking}
        for key in ("mpjpe_mm", "pa_mpjpe_mm", "acc_mm_per_frame2", "pa_acc_mm_per_frame2", "wrist_bend_mean_deg"):
            out[key] = float(np.average([r[key] for r in runs], weights=frames))
        out["wrist_bend_max_deg"] = max(r["wrist_bend_max_deg"] for r in runs)
        return out

    result = pool(rows)
    result.update(off=pool([r["off"] for r in rows]), motion="all", source_body=rows[0]["source_body"],
                  target_body=f"{len({r['target_body'] for r in rows})} avatars", frames=int(sum(r["frames"] for r in rows)),
                  **{"from": rows[0]["from"]})
    return result


if __name__ == "__main__":  # python -m live.evaluation.contacts [skeleton|depth] [--tune]
    import argparse
    import json
    import sys

    cli = argparse.ArgumentParser(prog="python -m live.evaluation.contacts",
                                  description="self-contacts kept and interpenetration on the held-out takes")
    cli.add_argument("which", nargs="?", default="skeleton", choices=["skeleton", "depth"])
    cli.add_argument("--json", type=Path, default=None, help="also write the results here")
    cli.add_argument("--tune", action="store_true",
                     help="the tuning takes and bodies the settings were chosen on, not the held-out ones")
    a = cli.parse_args()
    from live.evaluation.contact_clips import TUNING_TAKES

    runs = dict(takes=TUNING_TAKES, avatars=TUNING_AVATARS, performer=TUNING_PERFORMER) if a.tune else {}
    table = contact_table(a.which, progress=lambda msg: print(msg, file=sys.stderr, flush=True), **runs)
    print(format_report(table))
    if a.json is not None:
        a.json.write_text(json.dumps(table, indent=1))
