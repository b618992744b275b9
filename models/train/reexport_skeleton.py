"""Re-export a trained skeleton model in the current deployed form, without retraining.

    python -m models.train.reexport_skeleton [--model models/weights/skeleton.onnx]

Reads the weights of a ``VotingPointNet`` exported in its training form (the graph torch traces
from ``VotingPointNet.forward``: named BatchNorm and bias initialisers, MatMul weights named by
their node), loads them back into the torch network, checks that torch reproduces that ONNX
file, and writes ``DeployedVotingPointNet`` (models.train.skeleton_nets) over it: the same
function to float rounding, a smaller and faster graph. The model card records the export and
the largest joint difference between the two graphs; temporal model cards that named the old
file's sha256 are moved to the new one (their inputs change by that difference, ~1e-6 m).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from live.core import assets
from models.train.skeleton_nets import DeployedVotingPointNet, VotingPointNet, export_deployed, export_onnx

WEIGHTS = assets.weights_dir()


def module_name(matmul_output: str) -> str:
    """The torch module of a traced MatMul from its output name:
    "/refine.0/mlp/mlp.1/MatMul_output_0" -> "refine.0.mlp.1" (torch names each scope by its
    attribute path within the parent, so "mlp.1" inside "mlp" is attribute "1" of "mlp")."""
    scopes = matmul_output.strip("/").split("/")[:-1]
    name = scopes[0]
    for scope in scopes[1:]:
        head = scope.split(".")[0]
        name = name + scope[len(head):] if name.split(".")[-1] == head and "." in scope else f"{name}.{scope}"
    return name


def load_training_graph(path: Path, net: VotingPointNet) -> VotingPointNet:
    """``net`` with the weights of the training-form ONNX export at ``path``."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(path)).graph
    arrays = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    own = net.state_dict()
    state = {k: torch.from_numpy(v.copy()) for k, v in arrays.items() if k in own}
    for node in graph.node:
        if node.op_type == "MatMul" and node.input[1] in arrays and node.input[1].startswith("onnx::"):
            state[module_name(node.output[0]) + ".weight"] = torch.from_numpy(arrays[node.input[1]].T.copy())
    missing = [k for k in own if k not in state and not k.endswith("num_batches_tracked")]
    if missing:
        raise SystemExit(f"{path.name} is not a training-form VotingPointNet export (no {', '.join(missing[:3])} ...); "
                         "an already deployed file needs no re-export")
    state.update({k: own[k] for k in own if k not in state})
    net.load_state_dict(state)
    return net.eval()


def _deployed_tensors(d: DeployedVotingPointNet) -> list[tuple[object, object, int]]:
    """Every weight tensor of a deployed net as (container, key, index) so it can be replaced."""
    slots = []
    for pair in d.local:
        slots += [(pair, None, 0), (pair, None, 1)]
    for r in d.rounds:
        slots += [(r[0], None, 0), (r[0], None, 1), (r[1], None, 0), (r[1], None, 1), (r, None, 2)]
    slots += [(d.logit, None, 0), (d.logit, None, 1), (d.offset, None, 0), (d.offset, None, 1)]
    if d.refine is not None:
        for key in ("feature", "mlp1", "mlp2"):
            slots += [(d.refine, key, 0), (d.refine, key, 1)]
        slots += [(d.refine, "offset", None), (d.refine, "code", None)]
    return slots


def _get(slot):
    box, key, i = slot
    item = box[key] if key is not None else box
    return item if i is None else item[i]


def _set(slot, value: torch.Tensor) -> None:
    box, key, i = slot  # every container is a list or a dict (see load_deployed_graph)
    if i is None:
        box[key] = value
    else:
        (box[key] if key is not None else box)[i] = value


def _onnx_constants(path: Path) -> dict[str, np.ndarray]:
    import onnx
    from onnx import numpy_helper

    out = {}
    for node in onnx.load(str(path)).graph.node:
        if node.op_type == "Constant" and node.attribute and node.attribute[0].type == onnx.AttributeProto.TENSOR:
            out[node.output[0]] = numpy_helper.to_array(node.attribute[0].t)
    return out


def load_deployed_graph(path: Path, net: VotingPointNet, num_points: int, calibration: np.ndarray) -> VotingPointNet:
    """``net`` computing the function of a deployed export at ``path`` (BatchNorm folded), ready
    to train again. Which graph constant is which weight is found by exporting a deployed net of
    the same shape whose weights are distinct random markers. The folded BatchNorms are unfolded
    on ``calibration`` clouds (B, N, 3): each gets that batch's mean and spread of its input as
    running statistics and as its affine scale, so eval mode gives the file's function exactly and
    train mode, on batches like the calibration one, about the same."""
    import tempfile

    deployed = DeployedVotingPointNet(net, num_points)
    # tuples inside lists are immutable; make every container a list so slots can be written
    deployed.local = [list(pair) for pair in deployed.local]
    deployed.rounds = [[list(r[0]), list(r[1]), r[2]] for r in deployed.rounds]
    deployed.logit, deployed.offset = list(deployed.logit), list(deployed.offset)
    if deployed.refine is not None:
        deployed.refine = {k: (list(v) if isinstance(v, tuple) else v) for k, v in deployed.refine.items()}
    slots = _deployed_tensors(deployed)
    gen = torch.Generator().manual_seed(0)
    for slot in slots:
        _set(slot, torch.randn(_get(slot).shape, generator=gen))
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.onnx"
        export_deployed(deployed, str(probe))
        markers = _onnx_constants(probe)
    target = _onnx_constants(path)
    for slot in slots:
        m = _get(slot).numpy()
        for name, c in markers.items():
            if c.size != m.size or name not in target:
                continue
            if c.shape == m.shape and np.array_equal(c, m):
                value = target[name]
            elif c.shape == m.T.shape and np.array_equal(c, m.T):
                value = target[name].T
            elif np.array_equal(c.reshape(-1), m.reshape(-1)):
                value = target[name].reshape(m.shape)
            else:
                continue
            _set(slot, torch.from_numpy(np.array(value, dtype=np.float32)))
            break
        else:
            raise SystemExit(f"{path.name}: not a deployed export of this network (a weight of shape {m.shape} is missing)")
    return _unfold(deployed, net, torch.from_numpy(np.ascontiguousarray(calibration, np.float32)))


def _unfold(d: DeployedVotingPointNet, net: VotingPointNet, calibration: torch.Tensor) -> VotingPointNet:
    """Write the deployed weights into the training network (see ``load_deployed_graph``)."""
    def affine_bn(layer, bias: torch.Tensor, x: torch.Tensor) -> None:
        # BN(x) = (x - m) / s * s + (bias + m) = x + bias in eval mode, and on this batch in train mode
        mean, var = x.mean(0), x.var(0, unbiased=False)
        std = torch.sqrt(var + layer.eps)
        layer.running_mean.copy_(mean)
        layer.running_var.copy_(var)
        layer.weight.copy_(std)
        layer.bias.copy_(bias + mean)

    with torch.no_grad():
        n = d.n
        f = calibration.reshape(-1, 3)
        for layer, (w, b) in zip(net.local, d.local):
            layer.linear.weight.copy_(w.t())
            x = f @ w
            affine_bn(layer.norm, b, x)
            f = torch.relu(x + b)
        for to_g, mix_g, mix, ((w_g, b_g), (w_mg, b_mg), w_mix) in zip(net.to_global, net.mix_global, net.mix, d.rounds):
            to_g.linear.weight.copy_(w_g.t())
            x = f @ w_g
            affine_bn(to_g.norm, b_g.reshape(-1), x)
            g = torch.relu(x + b_g.reshape(-1)).reshape(-1, n, w_g.shape[1]).amax(dim=1)
            mix_g.weight.copy_(w_mg.t())
            mix_g.bias.copy_(b_mg)
            mix.linear.weight.copy_(w_mix.t())
            x = ((f @ w_mix).reshape(-1, n, w_mix.shape[1]) + (g @ w_mg + b_mg).unsqueeze(1)).reshape(-1, w_mix.shape[1])
            affine_bn(mix.norm, torch.zeros(w_mix.shape[1]), x)
            f = torch.relu(x)
        j = d.j
        head_w = torch.empty(j, 4, d.logit[0].shape[0])
        head_w[:, 0] = d.logit[0].t()
        head_w[:, 1:] = d.offset[0].permute(0, 2, 1)
        net.head.weight.copy_(head_w.reshape(j * 4, -1))
        net.head.bias.copy_(torch.cat([d.logit[1].reshape(j, 1), d.offset[1]], dim=1).reshape(-1))
        if d.refine is not None:
            r, stage = d.refine, net.refine[0]
            stage.feature.weight.copy_(r["feature"][0].t())
            stage.feature.bias.copy_(r["feature"][1])
            stage.offset.weight.copy_(r["offset"].t())
            stage.joint_code.copy_(r["code"])
            stage.mlp[1].weight.copy_(r["mlp1"][0].t())
            stage.mlp[1].bias.copy_(r["mlp1"][1])
            stage.mlp[3].weight.copy_(r["mlp2"][0].t())
            stage.mlp[3].bias.copy_(r["mlp2"][1])
    return net.eval()


def is_training_form(path: Path) -> bool:
    """Whether an export is the traced training graph (its BatchNorm statistics are named
    initialisers) rather than the deployed form (BatchNorm folded into the matmuls)."""
    import onnx

    return any(i.name.endswith("running_mean") for i in onnx.load(str(path)).graph.initializer)


def load_export(path: Path, net: VotingPointNet, num_points: int, calibration: np.ndarray) -> VotingPointNet:
    """``net`` with the weights of an export of either form (training graph or deployed)."""
    if is_training_form(path):
        return load_training_graph(path, net)
    return load_deployed_graph(path, net, num_points, calibration)


def sample_clouds(n: int, num_points: int, seed: int = 0) -> np.ndarray:
    """(n, num_points, 3) person-frame clouds spread over a standing body's box."""
    rng = np.random.default_rng(seed)
    box = rng.uniform(size=(n, num_points, 3)) * [0.6, 1.8, 0.3] - [0.3, 0.0, 0.15]
    return box.astype(np.float32)


def run_onnx(path: Path, points: np.ndarray) -> np.ndarray:
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return sess.run(None, {"points": np.ascontiguousarray(points, np.float32)})[0]


def main(argv: list[str] | None = None) -> float:
    from models.skeleton.temporal import file_sha256

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=WEIGHTS / "skeleton.onnx")
    args = ap.parse_args(argv)
    card_path = args.model.with_suffix(".json")
    card = json.loads(card_path.read_text())
    if card.get("architecture") != "VotingPointNet":
        raise SystemExit(f"{args.model.name}: only VotingPointNet models have a deployed form")
    num_points = int(card["num_points"])
    net = load_training_graph(args.model, VotingPointNet(**card["recipe"].get("net", {})))
    clouds = sample_clouds(16, num_points)
    before = run_onnx(args.model, clouds)
    with torch.no_grad():
        torch_diff = float(np.abs(net(torch.from_numpy(clouds)).numpy() - before).max())
    if torch_diff > 1e-4:
        raise SystemExit(f"the rebuilt torch network differs from {args.model.name} by {torch_diff:.2e} m")
    old_sha = file_sha256(args.model)
    tmp = args.model.with_suffix(".deployed.onnx")
    export_onnx(net, str(tmp), num_points)
    diff = float(np.abs(run_onnx(tmp, clouds) - before).max())
    if diff > 1e-4:
        tmp.unlink()
        raise SystemExit(f"the deployed export differs from {args.model.name} by {diff:.2e} m: not written")
    tmp.replace(args.model)
    new_sha = file_sha256(args.model)
    card["input"]["shape"] = ["batch", num_points, 3]
    card["export"] = {"form": DeployedVotingPointNet.__name__,
                      "command": "python -m models.train.reexport_skeleton",
                      "max_abs_diff_m_vs_training_graph": diff}
    card_path.write_text(json.dumps(card, indent=1) + "\n")
    for temporal_card in sorted(args.model.parent.glob("skeleton_temporal*.json")):
        t = json.loads(temporal_card.read_text())
        if t.get("regressor_sha256") == old_sha:
            t["regressor_sha256"] = new_sha
            t["regressor_reexported"] = (f"trained behind the training-form export (sha256 {old_sha[:12]}...); "
                                         f"the deployed form computes the same joints to {diff:.1e} m")
            temporal_card.write_text(json.dumps(t, indent=1) + "\n")
            print(f"{temporal_card.name}: regressor sha256 moved to the re-exported file")
    print(f"{args.model.name}: deployed form written (max |diff| {diff:.2e} m on {len(clouds)} clouds)")
    return diff


if __name__ == "__main__":
    main()
