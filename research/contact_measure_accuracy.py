"""How far the retarget stage's gap measure (live/retarget/contacts_surface.py ``measure``) is from
the exact distance to the skinned skin, on the rotation copy's poses of the tuning takes.

For every other frame of each tuning take (live/evaluation/contact_clips.py TUNING_TAKES, the
tuning performer) copied onto each tuning avatar, every (probe set, region) row the measure
returns within 10 cm is measured again exactly as the evaluation cuts the skin (faces of the
region's dominant-weight vertices, open edges outside, inside confirmed by winding number); the
rows within 3 cm by either count (a row the measure reads far while the skin is near is a
contact missed, as one read too deep is a push that was not needed).

    python -m research.contact_measure_accuracy [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

import live.retarget.contacts_surface as cs
from live.body.library import load_body
from live.body.skinning import lbs
from live.evaluation.contact_clips import TUNING_TAKES, take_motion
from live.evaluation.contacts import TUNING_AVATARS, TUNING_PERFORMER, skin_distances
from live.evaluation.retarget import make_retargeter, source_skeletons

#: Rows are measured out to LOOK (m) and kept where the measure or the exact distance is within NEAR.
LOOK = 0.10
NEAR = 0.03


def rows_of(avatar_name: str) -> list[tuple]:
    """(avatar, take, frame, probe set, region, measured gap, exact gap) per measured row."""
    performer, avatar = load_body(TUNING_PERFORMER), load_body(avatar_name)
    surface = cs.body_surface(avatar)
    faces = np.asarray(avatar.faces, np.int64)
    # Each region's skin as the evaluation cuts it: faces of two or more of its vertices (a
    # vertex's region: its heaviest joint's, as the measure assigns it).
    region_of = surface.model.vertex_region
    skins = {r: faces[cs.skin_faces(faces, region_of == k)] for k, r in enumerate(cs.REGIONS)}
    borders = {r: cs.border_vertices(f, len(region_of)) for r, f in skins.items()}
    out = []
    for take in TUNING_TAKES:
        motion = take_motion(*take, performer)
        joints, source_rest, _ = source_skeletons(motion, performer, "skeleton")
        retargeter = make_retargeter("analytic", source_rest, avatar.rest_joints, 30.0)
        for t, frame in enumerate(joints):
            root, quats, pos = retargeter.step(frame)
            if t % 2:
                continue
            gaps = cs.measure(surface, np.array(retargeter.last_globals), np.asarray(pos, np.float64), cs.ALL_PROBES,
                              LOOK, 0.003, LOOK)
            near = np.flatnonzero(gaps.gap < LOOK)
            if not len(near):
                continue
            v = lbs(avatar.vertices, avatar.weights, avatar.rest_joints, np.asarray(quats), np.asarray(root))[0]
            v = v.astype(np.float64)
            normals = cs.vertex_normals(v, faces)
            for row in near:
                region = cs.REGIONS[gaps.region[row]]
                pts = v[surface.model.probes[gaps.probe[row]]]
                d = skin_distances(v, normals, skins[region], pts, borders[region])
                if min(gaps.gap[row], d.min()) >= NEAR:
                    continue
                out.append((avatar_name, motion.name, t, cs.PROBES[gaps.probe[row]].name, region,
                            float(gaps.gap[row]), float(d.min())))
        print(f"{avatar_name} {motion.name}: {len(out)} rows", file=sys.stderr, flush=True)
    return out


def summary(rows: list[tuple]) -> dict[str, float]:
    err = 1000.0 * np.array([r[5] - r[6] for r in rows])
    return {"rows": len(rows), "median_abs_mm": float(np.median(np.abs(err))),
            "p95_abs_mm": float(np.percentile(np.abs(err), 95)), "p99_abs_mm": float(np.percentile(np.abs(err), 99)),
            "max_abs_mm": float(np.abs(err).max()), "deeper_by_10mm": int((err < -10).sum()),
            "shallower_by_10mm": int((err > 10).sum()), "farther_by_30mm": int((err > 30).sum())}


if __name__ == "__main__":
    cli = argparse.ArgumentParser(prog="python -m research.contact_measure_accuracy", description=__doc__.split("\n")[0])
    cli.add_argument("--json", default=None, help="also write the rows and the summary here")
    args = cli.parse_args()
    rows = [r for avatar in TUNING_AVATARS for r in rows_of(avatar)]
    result = summary(rows)
    print(json.dumps(result, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"summary": result, "rows": rows}, f)
