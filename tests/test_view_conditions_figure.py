"""research.view_conditions_figure: compare_skeleton's results as a bar chart."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from research.view_conditions_figure import bar_chart, main


def _results(values_by_model: dict[str, list[float]]) -> dict:
    groups = ("all", "posture:seated")
    return {"val_real": {m: {g: {"frames": 10, "root_aligned_pck_10cm": v} for g, v in zip(groups, vs)}
                         for m, vs in values_by_model.items()}}


def test_bars_grow_with_the_value():
    img = bar_chart([("a", [0.5, 0.9], 10)], ["low", "high"], "t", goal=0.85)
    colour = lambda k: np.all(img == np.array([(150, 150, 150), (40, 140, 240)][k], np.uint8), axis=2)  # noqa: E731
    widths = [int(colour(k).any(axis=0).sum()) for k in range(2)]
    assert widths[1] > widths[0] > 0


def test_writes_a_picture_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    path = tmp_path / "r.json"
    path.write_text(json.dumps(_results({"a.onnx": [0.77, 0.52], "b.onnx": [0.78, 0.60]})))
    out = tmp_path / "f.png"
    assert main([str(path), "--out", str(out), "--names", "shipped", "hard views"]) == 0
    assert cv2.imread(str(out)).shape[0] > 100
    for argv in ([str(tmp_path / "missing.json")], [str(path), "--split", "val"], [str(path), "--names", "one"]):
        with pytest.raises(SystemExit):
            main(argv + ["--out", str(out)])
        assert "error: " in capsys.readouterr().err.strip().splitlines()[-1]
