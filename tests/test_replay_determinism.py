"""Replays at max speed are deterministic: byte-identical result files, every frame processed."""

import json

import pytest

from live.cli import main
from sim.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_bvh):
    path = tmp_path_factory.mktemp("s") / "s.mcap"
    synthesize(SynthOptions(motion=str(shared_bvh / "cc_002_05.bvh"), body="performer", seconds=1.0, start_s=2.0,
                            imu="xbus", seed=1), path)
    return path


def test_two_replays_write_identical_files(session, tmp_path):
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        assert main(["replay", str(session), "--out", str(out), "--avatar", "default", "--quiet"]) == 0
        outs.append(out)
    stats = json.loads((outs[0] / "stats.json").read_text())
    assert stats["frames"] == 30 and stats["drops"] == {"ring_overwrites": 0, "skipped_for_latest": 0}
    files = sorted(p.name for p in outs[0].iterdir() if p.name != "stats.json")
    assert files == sorted(p.name for p in outs[1].iterdir() if p.name != "stats.json")
    for name in files:
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
