"""Run the depth chain over the training clips: the source skeletons train_retarget --chain-share learns from.

    python -m research.chain_sources [--runs-per-clip 2] [--frames 300] [--workers 2] [--clips N]

Each run puts a window of a training clip on a training body through the virtual OAK-D and the
shipped skeleton stage (models.train.chain_sources); prints how many runs and frames came out and
in how many frames the person was found. The runs are cached in .cache/, where train_retarget
finds them. The default set (96 clips x 2 runs of up to 300 frames) takes ~8 min on 2 cores.
"""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m research.chain_sources", description=__doc__.splitlines()[0])
    ap.add_argument("--runs-per-clip", type=int, default=2)
    ap.add_argument("--frames", type=int, default=300, help="frames per run (a window of the clip)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clips", type=int, default=None, help="only the first N training clips")
    a = ap.parse_args(argv)
    from models.train.chain_sources import build
    from models.train.train_retarget import load_clips  # the clips as the retargeter trains on them

    out = build(load_clips(), a.runs_per_clip, a.frames, a.workers, a.seed, a.clips)
    print(f"{len(out['clip'])} runs, {len(out['joints'])} frames, person found in {100 * out['found'].mean():.1f} %")
    return out


if __name__ == "__main__":
    main()
