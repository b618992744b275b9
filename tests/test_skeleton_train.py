"""Training smoke test: data generation, both networks, ONNX export, model card (--quick)."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("live.body.library")


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
    from models.skeleton.runtime import DEFAULT_MODEL, SkeletonRegressor, SkeletonStage
    from models.skeleton.temporal import file_sha256
    from models.train.train_skeleton_temporal import main

    card = main(["--quick", "--out", str(tmp_path), "--no-progress", "--workers", "2", "--threads", "1"])
    assert json.loads((tmp_path / "skeleton_temporal.json").read_text()) == json.loads(json.dumps(card))
    assert card["float32_onnx_max_abs_diff_m"] < 1e-4  # onnxruntime reproduces torch
    # The deployed file: the MLP's weights in 8-bit blocks, the linear filter path in float32.
    assert card["onnx_max_abs_diff_m"] < 5e-3
    assert [name.split("/")[1] for name in card["quantization"]["layers"]] == ["mlp"] * 4
    assert card["regressor_sha256"] == file_sha256(DEFAULT_MODEL)
    # Sequences sampled as the stage samples them for that regressor (its depth-edge test).
    edges = SkeletonRegressor(DEFAULT_MODEL).edge_jump_share
    assert edges is not None and card["recipe"]["edge_jump_share"] == edges
    assert card["data"]["train"]["found_frames"] > 0
    assert not set(card["data"]["val"]["bodies"]) & set(card["data"]["train"]["bodies"])
    val = card["metrics"]["val"]["on_performer"]
    assert set(val) == {"per_frame", "one_euro", "temporal", "temporal_float32"} and val["temporal"]["mpjpe_mm"] > 0
    # Training sequences partly performed in place; the held-out ones scored both ways.
    assert card["recipe"]["in_place_share"] == 0.3
    assert card["data"]["val_in_place"]["in_place_sequences"] == card["data"]["val"]["sequences"]
    assert card["metrics"]["val_in_place"]["on_performer"]["temporal"]["mpjpe_mm"] > 0
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
    _export_training_form(net, path)
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


def _export_training_form(net, path):
    """The training-form graph of earlier exports (what ``--init`` and the re-export read)."""
    torch.onnx.export(net, (_clouds(1),), str(path), input_names=["points"], output_names=["joints"],
                      dynamic_axes={"points": {0: "batch", 1: "num_points"}, "joints": {0: "batch"}},
                      opset_version=17, dynamo=False)


def test_fine_tune_starts_from_the_init_weights(tmp_path):
    """--init: training starts from the exported network's weights and BatchNorm statistics,
    not from a random initialisation."""
    from models.train.train_skeleton import Recipe, train_model

    net = _trained_looking_voting_net()
    path = tmp_path / "base.onnx"
    _export_training_form(net, path)
    rng = np.random.default_rng(0)
    train = {"points": _clouds(8).numpy(), "joints": rng.normal(size=(8, 22, 3)).astype(np.float32)}
    recipe = Recipe("ours", epochs=1, batch=4, lr=1e-12, loss="l1", num_points=64, schedule="constant",
                    max_steps=1, net={"refine_k": 8, "refine_width": 16})
    tuned, log = train_model(recipe, train, seed=1, progress=False, init=path)  # not the seed of net
    assert log["steps"] == 1
    start = dict(net.named_parameters())
    for name, param in tuned.named_parameters():
        assert torch.allclose(param, start[name], atol=1e-6), name  # a 1e-12 step moves nothing
    # (the BatchNorm scales of the base are not the 1.0 of a fresh network)
    assert not torch.allclose(tuned.local[1].norm.weight, torch.ones(()))


def test_deployed_export_unfolds_into_a_trainable_net(tmp_path):
    """A deployed file (BatchNorm folded) read back into the training network: eval mode computes
    the file's joints, train mode on the calibration clouds too (the unfolded BatchNorms take
    their statistics from them), and ``train_model(init=)`` accepts it."""
    from models.train.reexport_skeleton import is_training_form, load_deployed_graph, run_onnx
    from models.train.skeleton_nets import VotingPointNet, export_onnx
    from models.train.train_skeleton import Recipe, train_model

    path = tmp_path / "skeleton.onnx"
    export_onnx(_trained_looking_voting_net(), str(path), 64)
    assert not is_training_form(path)
    calibration = _clouds(6).numpy()
    torch.manual_seed(5)  # a different random start: everything must come from the file
    net = load_deployed_graph(path, VotingPointNet(refine_k=8, refine_width=16), 64, calibration)
    x = _clouds(4).numpy() + np.float32(0.01)
    with torch.no_grad():
        assert np.abs(net(torch.from_numpy(x)).numpy() - run_onnx(path, x)).max() < 1e-4
        assert np.abs(net.train()(torch.from_numpy(calibration)).numpy() - run_onnx(path, calibration)).max() < 1e-4
    train = {"points": calibration, "joints": np.zeros((6, 22, 3), np.float32)}
    recipe = Recipe("ours", epochs=1, batch=3, lr=1e-12, loss="l1", num_points=64, schedule="constant",
                    max_steps=1, net={"refine_k": 8, "refine_width": 16})
    tuned, _ = train_model(recipe, train, seed=1, progress=False, init=path)
    with torch.no_grad():  # one step in train mode moved only the BatchNorm running statistics a little
        assert np.abs(tuned(torch.from_numpy(x)).numpy() - run_onnx(path, x)).max() < 0.05


def test_weight_quantization_keeps_unselected_layers_in_float32(tmp_path):
    """models.train.quantize: the selected Gemm layers become 8-bit MatMulNBits, the others stay
    as they were, and the quantized graph computes the same function to the rounding of its
    weights."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnx_ir")
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    from models.train.quantize import quantize_matmuls

    rng = np.random.default_rng(0)
    w1, b1 = rng.standard_normal((64, 100)).astype(np.float32) * 0.1, rng.standard_normal(64).astype(np.float32)
    w2, b2 = rng.standard_normal((100, 8)).astype(np.float32) * 0.1, rng.standard_normal(8).astype(np.float32)
    graph = helper.make_graph(
        [helper.make_node("Gemm", ["x", "w1", "b1"], ["h"], name="/mlp/Gemm", transB=1),
         helper.make_node("Relu", ["h"], ["r"], name="/mlp/Relu"),
         helper.make_node("Gemm", ["r", "w2", "b2"], ["y"], name="/linear/Gemm")],
        "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["b", 100])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["b", 8])],
        [numpy_helper.from_array(a, n) for a, n in ((w1, "w1"), (b1, "b1"), (w2[:64], "w2"), (b2, "b2"))])
    src, dst = tmp_path / "f32.onnx", tmp_path / "q.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(src))
    info = quantize_matmuls(src, dst, quantize=lambda name: name.startswith("/mlp/"))
    ops = [n.op_type for n in onnx.load(str(dst)).graph.node]
    assert info["layers"] == ["/mlp/Gemm_matmul"] and info["float32_layers"] == ["/linear/Gemm"]
    assert ops.count("MatMulNBits") == 1 and ops.count("Gemm") == 1
    x = rng.standard_normal((16, 100)).astype(np.float32)
    want = np.maximum(x @ w1.T + b1, 0.0) @ w2[:64] + b2
    got = ort.InferenceSession(str(dst), providers=["CPUExecutionProvider"]).run(None, {"x": x})[0]
    np.testing.assert_allclose(got, want, atol=0.05 * np.abs(want).max())
    with pytest.raises(ValueError, match="quantized already"):
        quantize_matmuls(dst, tmp_path / "again.onnx", quantize=lambda name: True)


def test_fine_tune_reads_more_points_than_its_init_was_exported_with(tmp_path):
    """--num-points / refine_k above the init file's: the deployed file is read at its own point
    count (its card's), and the network then reads the recipe's (the weights depend on neither)."""
    import json

    from models.train.reexport_skeleton import run_onnx
    from models.train.skeleton_nets import export_onnx
    from models.train.train_skeleton import Recipe, train_model

    path = tmp_path / "skeleton.onnx"
    export_onnx(_trained_looking_voting_net(), str(path), 64)
    path.with_suffix(".json").write_text(json.dumps({"num_points": 64}))
    clouds = _clouds(6, 96).numpy()
    train = {"points": clouds, "joints": np.zeros((6, 22, 3), np.float32)}
    recipe = Recipe("ours", epochs=1, batch=3, lr=1e-12, loss="l1", num_points=96, schedule="constant",
                    max_steps=1, net={"refine_k": 12, "refine_width": 16})
    tuned, log = train_model(recipe, train, seed=1, progress=False, init=path)
    assert log["steps"] == 1
    x = clouds[:2, :64] + np.float32(0.01)
    tuned.refine[0].k = 8  # the file's own reading: the same function
    with torch.no_grad():
        assert np.abs(tuned.eval()(torch.from_numpy(x)).numpy() - run_onnx(path, x)).max() < 0.05
    wide = tmp_path / "wide.onnx"
    tuned.refine[0].k = 12
    export_onnx(tuned, str(wide), 96)
    assert run_onnx(wide, clouds[:2]).shape == (2, 22, 3)
