"""Export the body library from Anny (needs the train extra: torch and anny).

    python -m models.train.export_bodies --out models/bodies

Builds every body that models/bodies/library.json lists, from its phenotype there, with
models.train.anny_bodies (how a body is made from a phenotype), saves one body file each into ``--out``
(CONVENTIONS.md) and writes library.json there with each body's measured height and vertex
count. Deterministic: the same anny and open3d versions regenerate the committed files byte for
byte. To add or change a body, edit its phenotype in library.json and run this.

    python -m models.train.export_bodies --anny 'anny:gender=0.3,age=0.6,...' [...]
    (livecap train bodies --anny SPEC)

builds ``anny:`` bodies into the body cache instead, where ``--body`` / ``--avatar anny:...``
read them without torch.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from live.core import assets


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    from live.body.library import aliases, anny_body_path, preset_phenotypes, save_body
    from models.train import anny_bodies

    parser = argparse.ArgumentParser(prog="python -m models.train.export_bodies",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=assets.bodies_dir(),
                        help="folder for the body files and library.json (default: the shipped library)")
    parser.add_argument("--anny", nargs="+", metavar="SPEC", default=None,
                        help="build these anny:key=value,... bodies into the body cache instead of the library")
    args = parser.parse_args(argv)
    if args.anny:
        built = anny_bodies.ensure_built(args.anny, progress=True)
        for spec in args.anny:
            print(f"{spec}: {anny_body_path(spec)}{' (built)' if spec in built else ' (already built)'}")
        return 0
    library, alias_table = preset_phenotypes(), aliases()  # read before --out's library.json is rewritten
    args.out.mkdir(parents=True, exist_ok=True)
    summary = {}
    for name, pheno in tqdm(library.items(), desc="bodies", unit="body"):
        body = anny_bodies.build_body(pheno, name)
        save_body(args.out / f"{name}.npz", body)
        summary[name] = {"height_m": round(float(body.vertices[:, 1].max()), 3), "vertices": len(body.vertices),
                         "phenotype": pheno}
    (args.out / "library.json").write_text(json.dumps({"aliases": alias_table, "bodies": summary}, indent=2) + "\n")
    for name, s in summary.items():
        print(f"{name:24s} {s['height_m']:.2f} m  {s['vertices']} vertices")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
