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

from models.train.skeleton_nets import DeployedVotingPointNet, VotingPointNet, export_onnx

WEIGHTS = Path(__file__).resolve().parents[2] / "models" / "weights"


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
