"""Training smoke test: data generation, both networks, ONNX export, model card (--quick)."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("live.body")


def test_quick_training_exports_models_and_cards(tmp_path):
    import onnxruntime as ort

    from models.train.train_skeleton import main

    cards = main(["--quick", "--out", str(tmp_path), "--n-train", "64", "--n-val", "24", "--no-progress",
                  "--no-cache", "--workers", "2"])
    assert set(cards) == {"ours", "baseline"}
    for name, kind in (("skeleton", "ours"), ("skeleton_baseline", "baseline")):
        card = json.loads((tmp_path / f"{name}.json").read_text())
        assert card == json.loads(json.dumps(cards[kind]))
        assert card["onnx_max_abs_diff_m"] < 1e-4  # onnxruntime reproduces torch
        assert card["split"]["val_subjects"] == [7, 8, 12, 16]
        assert not set(card["split"]["val_bodies"]) & set(card["split"]["train_bodies"])
        assert card["data"]["train"]["samples"] > 40
        assert not set(card["data"]["train"]["subjects"]) & {7, 8, 12, 16}
        assert set(card["data"]["val"]["subjects"]) <= {7, 8, 12, 16}
        assert set(card["data"]["val"]["bodies"]) <= set(card["split"]["val_bodies"])
        m = card["metrics"]["val"]
        assert m["mpjpe_mm"] > 0 and 0 <= m["pck_10cm"] <= 1 and len(m["per_joint_mm"]) == 22
        sess = ort.InferenceSession(str(tmp_path / f"{name}.onnx"), providers=["CPUExecutionProvider"])
        out = sess.run(None, {"points": np.zeros((2, card["num_points"], 3), np.float32)})[0]
        assert out.shape == (2, 22, 3)
    assert cards["baseline"]["parameters"] > 10 * cards["ours"]["parameters"]


def test_networks_shapes_and_reference_normalisation():
    from models.train.skeleton_nets import ReferencePointNet, VotingPointNet

    torch.manual_seed(0)
    pts = torch.randn(3, 128, 3)
    for net in (VotingPointNet(), ReferencePointNet()):
        assert net.eval()(pts).shape == (3, 22, 3)
    # The reference network is invariant to where the cloud is and how big it is, up to the
    # undone normalisation: moving the input moves the output by the same amount.
    net = ReferencePointNet().eval()
    shift = torch.tensor([0.5, -0.2, 1.0])
    with torch.no_grad():
        np.testing.assert_allclose((net(pts + shift) - shift).numpy(), net(pts).numpy(), atol=1e-5)


def test_refinement_stage_votes_from_each_joints_nearest_points():
    """With its last layer zeroed (uniform weights, no offsets), a refinement stage returns, for
    every joint, the mean of the k sample points nearest the previous estimate: the gather picks
    the right points for every joint of every cloud in the batch."""
    from models.train.skeleton_nets import VotingPointNet

    torch.manual_seed(1)
    net = VotingPointNet(refine_k=5, refine_width=16, refine_stages=1).eval()
    last = net.refine[0].mlp[-1]
    torch.nn.init.zeros_(last.weight)
    torch.nn.init.zeros_(last.bias)
    pts = torch.rand(2, 64, 3)
    with torch.no_grad():
        coarse, refined = (x.numpy() for x in net.stages(pts))
    p = pts.numpy()
    for b in range(2):
        for j in range(22):
            near = np.argsort(((p[b] - coarse[b, j]) ** 2).sum(-1))[:5]
            np.testing.assert_allclose(refined[b, j], p[b, near].mean(axis=0), atol=1e-5)


def test_quick_temporal_training_exports_a_model_the_stage_runs(tmp_path):
    from models.skeleton.runtime import DEFAULT_MODEL, SkeletonStage
    from models.skeleton.temporal import file_sha256
    from models.train.train_skeleton_temporal import main

    card = main(["--quick", "--out", str(tmp_path), "--no-progress", "--workers", "2", "--threads", "1"])
    assert json.loads((tmp_path / "skeleton_temporal.json").read_text()) == json.loads(json.dumps(card))
    assert card["onnx_max_abs_diff_m"] < 1e-4
    assert card["regressor_sha256"] == file_sha256(DEFAULT_MODEL)
    assert card["data"]["train"]["found_frames"] > 0
    assert not set(card["data"]["val"]["bodies"]) & set(card["data"]["train"]["bodies"])
    val = card["metrics"]["val"]["on_performer"]
    assert set(val) == {"per_frame", "one_euro", "temporal"} and val["temporal"]["mpjpe_mm"] > 0
    stage = SkeletonStage(temporal=tmp_path / "skeleton_temporal.onnx")
    assert stage.temporal is not None and stage.temporal.window == card["window"]
    assert stage.use_filter is False  # the temporal model replaces One Euro by default


def _trained_looking_voting_net():
    """A VotingPointNet with a refine stage and non-trivial BatchNorm statistics, in eval mode."""
    from models.train.skeleton_nets import VotingPointNet

    torch.manual_seed(0)
    net = VotingPointNet(refine_k=8, refine_width=16)
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm1d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
            m.weight.data.uniform_(0.5, 1.5)
            m.bias.data.uniform_(-0.2, 0.2)
    return net.eval()


def _clouds(n=3, points=64):
    from models.train.reexport_skeleton import sample_clouds

    return torch.from_numpy(sample_clouds(n, points))


def test_deployed_voting_net_is_the_same_function():
    from models.train.skeleton_nets import DeployedVotingPointNet

    net = _trained_looking_voting_net()
    x = _clouds()
    with torch.no_grad():
        assert torch.allclose(DeployedVotingPointNet(net, 64)(x), net(x), atol=1e-5)


def test_reexport_rebuilds_the_training_graph_and_moves_temporal_cards(tmp_path):
    from models.skeleton.temporal import file_sha256
    from models.train.reexport_skeleton import main, run_onnx

    net = _trained_looking_voting_net()
    path = tmp_path / "skeleton.onnx"
    example = _clouds(1)
    torch.onnx.export(net, (example,), str(path), input_names=["points"], output_names=["joints"],
                      dynamic_axes={"points": {0: "batch", 1: "num_points"}, "joints": {0: "batch"}},
                      opset_version=17, dynamo=False)  # the training-form graph of earlier exports
    card = {"architecture": "VotingPointNet", "num_points": 64, "input": {"shape": ["batch", "num_points", 3]},
            "recipe": {"net": {"refine_k": 8, "refine_width": 16}}}
    path.with_suffix(".json").write_text(json.dumps(card))
    old_sha = file_sha256(path)
    (tmp_path / "skeleton_temporal.json").write_text(json.dumps({"regressor_sha256": old_sha}))
    x = _clouds(4).numpy()
    before = run_onnx(path, x)
    assert main(["--model", str(path)]) < 1e-4
    assert np.abs(run_onnx(path, x) - before).max() < 1e-4
    assert json.loads((tmp_path / "skeleton_temporal.json").read_text())["regressor_sha256"] == file_sha256(path)
    assert json.loads(path.with_suffix(".json").read_text())["export"]["form"] == "DeployedVotingPointNet"
    with pytest.raises(SystemExit, match="no re-export"):
        main(["--model", str(path)])  # already deployed
