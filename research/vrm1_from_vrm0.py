"""A VRM 1.0 file from a VRM 0.x one (the VRM 1.0 test avatar: Godette converted, CC BY 3.0).

    python -m research.vrm1_from_vrm0 ../shared/data/avatars/godette_vrm0.vrm OUT.vrm

What changes: the ``VRM`` extension becomes ``VRMC_vrm`` (specVersion 1.0) with the humanoid bones
in the 1.0 form ({bone: {"node": i}}) and the meta in the 1.0 fields (name, authors, license URL,
the original's credit kept); the scene's root nodes are turned 180 degrees about y, so the avatar
faces +z as VRM 1.0 asks (the skinned meshes follow their joints; the buffers are unchanged). The
0.x blend shapes, first-person and spring-bone settings are left out (livecap does not use them).
The output is a derived work of the input: keep its credit, never commit it (tests write it into
a temporary folder).
"""

from __future__ import annotations

import argparse
from pathlib import Path

#: glTF quaternion (x, y, z, w) of a half turn about +y.
HALF_TURN_Y = [0.0, 1.0, 0.0, 0.0]


def _quat_mul_xyzw(a: list[float], b: list[float]) -> list[float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def convert(src: Path, out: Path) -> dict:
    """Write the VRM 1.0 file; returns its ``VRMC_vrm`` extension."""
    import pygltflib

    doc = pygltflib.GLTF2.load_binary(str(src))
    vrm0 = (doc.extensions or {}).get("VRM")
    if not isinstance(vrm0, dict):
        raise SystemExit(f"{src}: not a VRM 0.x file (no VRM extension)")
    bones = {b["bone"]: {"node": b["node"]} for b in vrm0["humanoid"]["humanBones"]
             if isinstance(b.get("node"), int) and b["node"] >= 0}
    meta0 = vrm0.get("meta") or {}
    credit = f"VRM 1.0 conversion by livecap research/vrm1_from_vrm0.py of {src.name}"
    vrm1 = {
        "specVersion": "1.0",
        "meta": {
            "name": meta0.get("title") or src.stem,
            "version": meta0.get("version") or "",
            "authors": [meta0.get("author") or "unknown"],
            "copyrightInformation": meta0.get("contactInformation") or "",
            "references": [meta0["reference"]] if meta0.get("reference") else [],
            "licenseUrl": "https://creativecommons.org/licenses/by/3.0/",
            "creditNotation": "required",
            "otherLicenseUrl": meta0.get("otherLicenseUrl") or "",
            "avatarPermission": "everyone",
            "allowRedistribution": True,
            "modification": "allowModificationRedistribution",
            "commercialUsage": "corporation",
            "allowExcessivelyViolentUsage": False,
            "allowExcessivelySexualUsage": False,
            "allowPoliticalOrReligiousUsage": False,
            "allowAntisocialOrHateUsage": False,
        },
        "humanoid": {"humanBones": bones},
        "extras": {"credit": credit},
    }
    ext = dict(doc.extensions or {})
    ext.pop("VRM", None)
    ext["VRMC_vrm"] = vrm1
    doc.extensions = ext
    doc.extensionsUsed = [e for e in (doc.extensionsUsed or []) if e != "VRM"] + ["VRMC_vrm"]
    for root in doc.scenes[doc.scene or 0].nodes:
        node = doc.nodes[root]
        if node.matrix is not None:
            raise SystemExit(f"{src}: scene root {root} has a matrix; only TRS roots are turned here")
        node.rotation = _quat_mul_xyzw(HALF_TURN_Y, list(node.rotation or [0.0, 0.0, 0.0, 1.0]))
        if node.translation is not None:
            x, y, z = node.translation
            node.translation = [-x, y, -z]
    out.parent.mkdir(parents=True, exist_ok=True)
    doc.save_binary(str(out))
    return vrm1


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path, help="a VRM 0.x file")
    ap.add_argument("out", type=Path, help="the VRM 1.0 file to write")
    args = ap.parse_args(argv)
    vrm1 = convert(args.src, args.out)
    print(f"wrote {args.out}: VRM 1.0, {len(vrm1['humanoid']['humanBones'])} humanoid bones, facing +z")


if __name__ == "__main__":
    main()
