"""Picture of the self-contact correction: hands on the hips and clapping, performed on a
held-out body, retargeted onto the slimmest child and the heaviest adult of the body library,
without and with the correction (docs/img/contacts.png).

    python -m research.contacts_figure [--out docs/img/contacts.png]

The takes are held-out subjects' walks made into contact clips (live/evaluation/contact_clips.py;
CMU subjects 7 and 8), retargeted from their exact skeletons as ``livecap eval contacts`` does.
Hands and forearms are drawn blue; where their skin is inside the body, red (measured on the
skinned mesh). Each caption gives the frame's hand gap to what the performer touches (cm,
negative: sunk in) and the arms' deepest point inside the body (mm).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from live.body.library import load_body
from live.body.skinning import lbs
from live.core.skeleton import JOINT_INDEX
from live.evaluation.contact_clips import take_motion
from live.evaluation.contacts import (
    CONTACT_AVATARS,
    CONTACT_PERFORMER,
    REGIONS,
    BodyRegions,
    contact_geometry,
    run_retargeter,
)
from live.evaluation.retarget import _on_body, make_retargeter, source_skeletons
from live.outputs.raster import look_at, rasterize, shade_lambert, vertex_normals, world_to_camera
from live.retarget.analytic import local_rotations_from_joints
from live.retarget.contacts_retargeter import ContactRetargeter
from live.retarget.contacts_surface import body_surface, signed_distances
from live.retarget.contacts_surface import vertex_normals as skin_normals

OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "contacts.png"
#: (take, frame shown, region the hands touch, camera yaw in degrees from the front)
SCENES = ((("cc_007_04.bvh", 0, 150, "hands-on-hips"), 90, "torso", 35.0),
          (("mb_08_04.bvh", 0, 150, "clapping"), 80, "hand", 25.0))
TILE = (240, 280)
SKIN = np.array([0.85, 0.72, 0.62])
ARM = np.array([0.35, 0.55, 0.9])
SUNK = np.array([0.9, 0.15, 0.1])


def _inside(body, regions: BodyRegions, vertices: np.ndarray) -> np.ndarray:
    """(V,) bool: hand and forearm vertices inside the torso, head, legs or the other arm."""
    faces = np.asarray(body.faces, np.int64)
    normals = skin_normals(vertices, faces)
    inside = np.zeros(len(vertices), bool)
    for a, side in enumerate(("left", "right")):
        arm = np.concatenate([regions.hand[a], regions.forearm[a]])
        other = "right" if side == "left" else "left"
        for skin in ("torso", "head", "legs", f"{other}_hand", f"{other}_arm"):
            d = signed_distances(vertices, normals, regions.skins[skin], vertices[arm], regions.borders[skin])[0]
            inside[arm[d < -0.001]] = True
    return inside


def _render(body, vertices: np.ndarray, yaw_deg: float, centre: np.ndarray, caption: list[str]) -> np.ndarray:
    regions = BodyRegions.of(body)
    colours = np.tile(SKIN, (len(vertices), 1))
    arms = np.concatenate(regions.hand + regions.forearm)
    colours[arms] = ARM
    colours[_inside(body, regions, vertices)] = SUNK
    w, h = TILE
    yaw = np.radians(yaw_deg)
    eye = centre + 1.7 * np.array([np.sin(yaw), 0.2, np.cos(yaw)])
    cam = world_to_camera(vertices, look_at(eye, centre))
    f = 0.9 * h
    k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    faces = np.asarray(body.faces)
    raster = rasterize(cam.astype(np.float32), faces, k, (w, h))
    idx = np.flatnonzero(raster.face.ravel() >= 0)
    tri = faces[raster.face.ravel()[idx]]
    bary = raster.bary.reshape(-1, 3)[idx]
    albedo = np.einsum("pc,pci->pi", bary, colours[tri])
    img = shade_lambert(raster, vertex_normals(cam, faces), faces, background=(255, 255, 255), albedo=albedo)
    img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    for i, line in enumerate(caption):
        cv2.putText(img, line, (6, 16 + 15 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (30, 30, 30), 1, cv2.LINE_AA)
    return img


def contacts_figure(out: Path = OUT) -> Path:
    performer = load_body(CONTACT_PERFORMER)
    rows = []
    for take, frame, touched, yaw in SCENES:
        motion = take_motion(*take, performer)
        joints, rest, _ = source_skeletons(motion, performer, "skeleton")
        root, src_joints = _on_body(motion, performer.rest_joints)
        src_pose = local_rotations_from_joints(src_joints, performer.rest_joints)
        src_verts = lbs(performer.vertices, performer.weights, performer.rest_joints, src_pose[frame], root[frame])[0]
        centre = src_joints[frame, JOINT_INDEX["spine2"]]
        gaps, depth = contact_geometry(BodyRegions.of(performer), np.asarray(performer.faces, np.int64), src_verts[None])
        col = list(REGIONS).index(touched)
        tiles = [_render(performer, src_verts.astype(np.float64), yaw, centre,
                         [f"performer ({take[3]})", f"hands {100 * gaps[0, 0, col]:.1f} / {100 * gaps[0, 1, col]:.1f} cm"])]
        for name in CONTACT_AVATARS:
            avatar = load_body(name)
            for label, keep in (("before", False), ("after", True)):
                rt = make_retargeter("analytic", rest, avatar.rest_joints, 30.0)
                if keep:
                    rt = ContactRetargeter(rt, body_surface(avatar), avatar.rest_joints, rest, body_surface(performer))
                r, q, pred = run_retargeter(rt, joints[:frame + 1])
                verts = lbs(avatar.vertices, avatar.weights, avatar.rest_joints, q[frame], r[frame])[0]
                g, d = contact_geometry(BodyRegions.of(avatar), np.asarray(avatar.faces, np.int64), verts[None])
                tiles.append(_render(avatar, verts.astype(np.float64), yaw, pred[frame, JOINT_INDEX["spine2"]],
                                     [f"{name.replace('_', ' ')}, {label}",
                                      f"hands {100 * g[0, 0, col]:.1f} / {100 * g[0, 1, col]:.1f} cm",
                                      f"sunk in {max(1000 * d[0].max(), 0.0):.0f} mm"]))
        rows.append(np.hstack(tiles))
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.vstack(rows))
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m research.contacts_figure", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    print(contacts_figure(p.parse_args(argv).out))


if __name__ == "__main__":
    main()
