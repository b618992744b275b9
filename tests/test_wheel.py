"""The installed package works outside a checkout: the wheel holds the models, bodies and demo
session but no research code, and `livecap demo` runs from it in another directory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q",
                            "-w", str(out), str(ROOT)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    return next(out.glob("livecap-*.whl"))


def test_wheel_holds_the_assets_and_no_research(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    assert not [n for n in names if n.startswith(("research/", "tests/", "benchmarks/"))]
    for needed in ("models/weights/skeleton.onnx", "models/weights/skeleton_temporal.onnx",
                   "models/bodies/library.json", "models/bodies/child_boy_9y.npz", "sim/data/demo.mcap",
                   "drivers/layouts/full_body.json", "live/py.typed"):
        assert needed in names


def test_demo_runs_from_the_installed_wheel_in_another_directory(wheel, tmp_path):
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    code = ("import sys, live; assert live.__file__.startswith(sys.argv[1]), live.__file__\n"
            "from live.app.cli import main; sys.exit(main(['demo', '--out', 'out', '--no-video', '--quiet']))")
    run = subprocess.run([sys.executable, "-c", code, str(site)], cwd=work, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    stats = json.loads((work / "out" / "stats.json").read_text())
    assert stats["frames"] == 150
    assert (work / "out" / "avatar.bvh").stat().st_size > 0
    assert "torch" not in run.stderr
