"""`livecap batch`: the same outputs as the single commands, byte for byte, on a local process
pool or in process; resumable; a bad session recorded while the rest complete. (Ray: test_batch_ray.py.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from live.app.cli import main

ROOT = Path(__file__).resolve().parents[1]
RESULT_FILES = ("skeleton.npz", "avatar.npz", "avatar.bvh")


def make_sessions(folder: Path, clips: Path, count: int = 2) -> list[Path]:
    """``count`` one-second synthetic sessions (different clips and seeds)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, clip in enumerate(["cc_001_01.bvh", "cc_002_01.bvh", "cc_002_02.bvh"][:count]):
        path = folder / f"take{i}.mcap"
        assert main(["synth", "--motion", str(clips / clip), "--out", str(path), "--seconds", "1", "--seed", str(i),
                     "--quiet"]) == 0
        paths.append(path)
    return paths


def reference_replays(sessions: list[Path], folder: Path, *options: str) -> dict[str, Path]:
    """Each session through plain `livecap replay --speed max`, one after the other."""
    out = {}
    for s in sessions:
        out[s.stem] = folder / s.stem
        assert main(["replay", str(s), "--out", str(out[s.stem]), "--speed", "max", "--quiet", *options]) == 0
    return out


def assert_same_results(batch_dir: Path, reference: dict[str, Path]) -> None:
    for name, ref in reference.items():
        for f in RESULT_FILES:
            assert (batch_dir / name / f).read_bytes() == (ref / f).read_bytes(), f"{name}/{f} differs"


def records(batch_dir: Path, key: str = "sessions") -> dict:
    return json.loads((batch_dir / "batch.json").read_text())[key]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, shared_bvh) -> list[Path]:
    return make_sessions(tmp_path_factory.mktemp("sessions"), shared_bvh)


@pytest.fixture(scope="module")
def reference(sessions, tmp_path_factory) -> dict[str, Path]:
    return reference_replays(sessions, tmp_path_factory.mktemp("reference"), "--avatar", "default")


def test_process_pool_matches_sequential_replay_and_a_second_run_skips(sessions, reference, tmp_path, capsys):
    out = tmp_path / "batch"
    argv = ["batch", "replay", *map(str, sessions), "--out", str(out), "--avatar", "default", "--workers", "2"]
    assert main(argv) == 0
    assert_same_results(out, reference)
    recs = records(out)
    assert {r["status"] for r in recs.values()} == {"done"}
    assert all(r["frames"] == 30 and r["accuracy"]["frames_scored"] == 30 for r in recs.values())
    totals = json.loads((out / "batch.json").read_text())["totals"]
    assert totals["done"] == 2 and totals["executor"] == "process pool" and totals["accuracy"]["sessions"] == 2
    assert "2 done" in capsys.readouterr().out
    # Again: same inputs, models and options -> nothing made again, the files untouched.
    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")}
    assert main(argv) == 0
    assert {r["status"] for r in records(out).values()} == {"skipped"}
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")} == mtimes
    # Other options: a new key, so made again; an output removed: made again.
    (out / "take0" / "avatar.bvh").unlink()
    assert main(argv[:-2] + ["--workers", "1"]) == 0
    assert records(out)["take0"]["status"] == "done" and records(out)["take1"]["status"] == "skipped"
    assert main(argv[:-2] + ["--workers", "1", "--bvh-names", "canonical"]) == 0
    assert {r["status"] for r in records(out).values()} == {"done"}
    assert not (out / ".partial").exists()


def test_a_corrupt_or_missing_session_is_recorded_and_the_rest_complete(sessions, reference, tmp_path, capsys):
    lists = tmp_path / "lists"
    lists.mkdir()
    (lists / "broken.mcap").write_bytes(bytes(range(256)) * 40)  # not an MCAP file at all
    (lists / "cut.mcap").write_bytes(sessions[0].read_bytes()[:1_000_000])  # an unfinished recording
    listing = lists / "sessions.txt"
    listing.write_text("# good, broken, cut short, a typo\n" + "".join(f"{s}\n" for s in sessions)
                       + "broken.mcap\n\ncut.mcap\nmissing.mcap\n")
    out = tmp_path / "batch"
    assert main(["batch", "replay", "--list", str(listing), "--out", str(out), "--avatar", "default",
                 "--workers", "2", "--quiet"]) == 1
    recs = records(out)
    assert recs["take0"]["status"] == recs["take1"]["status"] == "done"
    assert recs["broken"]["status"] == "failed" and "broken.mcap" in recs["broken"]["error"]
    assert recs["missing"]["status"] == "failed" and "no such file" in recs["missing"]["error"]
    # Read around its damage, as `livecap replay` does (exit 1): made, with what was lost said.
    assert recs["cut"]["status"] == "done" and "damaged region" in recs["cut"]["warning"]
    assert 0 < recs["cut"]["frames"] < 30
    assert_same_results(out, reference)
    assert not (out / "broken").exists()
    err = capsys.readouterr().err
    assert "broken failed:" in err and "missing failed:" in err


def test_inputs_and_outputs_as_fsspec_urls(sessions, reference, tmp_path):
    pytest.importorskip("fsspec")
    out = f"file://{tmp_path}/batch"
    assert main(["batch", "replay", f"file://{sessions[0]}", "--out", out, "--avatar", "default", "--workers", "1",
                 "--quiet"]) == 0
    assert_same_results(tmp_path / "batch", {"take0": reference["take0"]})
    assert main(["batch", "replay", "nosuchprotocol://x/take.mcap", "--out", str(tmp_path / "b2"), "--workers", "1"]) == 2


def test_batch_synth_writes_what_synth_writes_and_resumes(shared_bvh, tmp_path):
    clip = shared_bvh / "cc_001_01.bvh"
    out = tmp_path / "set"
    argv = ["batch", "synth", "--motion", str(clip), "--body", "performer", "tall_thin_male", "--seeds", "0,5",
            "--seconds", "0.2", "--out", str(out), "--workers", "2", "--quiet"]
    assert main(argv) == 0
    names = sorted(p.name for p in out.glob("*.mcap"))
    assert names == [f"cc_001_01__{b}__oak-d__s{s}.mcap" for b in ("performer", "tall_thin_male") for s in (0, 5)]
    single = tmp_path / "single.mcap"
    assert main(["synth", "--motion", str(clip), "--body", "tall_thin_male", "--seed", "5", "--seconds", "0.2",
                 "--out", str(single), "--quiet"]) == 0
    assert (out / "cc_001_01__tall_thin_male__oak-d__s5.mcap").read_bytes() == single.read_bytes()
    # A shard of the same batch finds its items made; the whole batch again skips them all.
    assert main(argv + ["--shard", "1/2"]) == 0
    assert {r["status"] for r in records(out, "items").values()} == {"done"}
    assert {r["status"] for r in json.loads((out / "batch-shard-1-of-2.json").read_text())["items"].values()} == {"skipped"}
    assert main(argv) == 0
    assert {r["status"] for r in records(out, "items").values()} == {"skipped"}


@pytest.mark.parametrize("argv, says", [
    (["batch", "replay", "--out", "x"], "no sessions"),
    (["batch", "replay", "a.mcap", "--out", "x", "--list", "nope.txt"], "no such list file"),
    (["batch", "replay", "a.mcap", "--out", "x", "--shard", "3/3"], "--shard wants I/N"),
    (["batch", "replay", "a.mcap", "--out", "x", "--avatar", "no_such_body"], "no_such_body"),
    (["batch", "synth", "--motion", "nope.bvh", "--out", "x"], "no such motion"),
    (["batch", "synth", "--motion", "nope.bvh", "--out", "x", "--seeds", "-3"], "--seeds"),
])
def test_user_mistakes_are_one_line(argv, says, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "nope.bvh").write_text("") if "--seeds" in argv else None
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]


def test_without_ray_a_process_pool_and_how_to_get_ray(sessions, tmp_path, monkeypatch, capsys):
    import live.app.batch_ray as batch_ray

    monkeypatch.setattr(batch_ray, "ray_installed", lambda: False)
    assert main(["batch", "replay", str(sessions[0]), "--out", str(tmp_path / "b")]) == 0
    captured = capsys.readouterr()
    assert "pip install 'livecap[cluster]'" in captured.err and "process pool" in captured.out
    assert main(["batch", "replay", str(sessions[0]), "--out", str(tmp_path / "b"), "--ray", "auto"]) == 2
    assert "livecap[cluster]" in capsys.readouterr().err


def test_the_cli_and_the_batch_command_do_not_import_ray():
    code = ("import sys, live.app.cli, live.app.batch, live.app.batch_items\n"
            "live.app.cli.build_parser()\n"
            "print(','.join(m for m in sys.modules if m.split('.')[0] == 'ray'))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_the_camera_height_passes_on_to_each_replay():
    import argparse

    from live.app.batch_args import REPLAY_OPTIONS, passthrough
    from live.app.cli import build_parser

    given = argparse.Namespace(**{flag.lstrip("-").replace("-", "_"): None for flag, _ in REPLAY_OPTIONS})
    given.camera_height = 1.1
    line = passthrough(given, REPLAY_OPTIONS)
    assert line == ["--camera-height", "1.1"]
    assert build_parser().parse_args(["replay", "s.mcap", "--out", "o", *line]).camera_height == 1.1
