"""Skeleton regression networks (torch, training only; the runtime runs their ONNX export).

Both take person-frame points B x N x 3 (metres, see models.skeleton.preprocess) and return
person-frame joints B x 22 x 3, so that the runtime, the evaluation and the export treat them
the same way.

- ``ReferencePointNet``: the published reference PointNet baseline: input centred on its
  centroid and scaled into the unit cube, input STN (k=3), conv 3->64, feature STN (k=64),
  conv 64->128->1024, max-pool, FC 1024->512->256 (dropout 0.3) -> 66, ReLU; the normalisation
  is undone on the output; BatchNorm after every layer but the last, as in the original
  PointNet. 3.5 M parameters with the feature STN ("about 1.6 M" is the count without it;
  see docs/skeleton.md).
- ``VotingPointNet`` (ours): every point votes for every joint. A shared per-point MLP
  (3->64->128), a global max-pooled feature (->256), then per point and joint a weight logit and
  a 3D offset; joint j = sum_n softmax_n(w_nj) * (p_n + o_nj). Votes are local, so a joint is
  placed from the points near it; ~0.2 M parameters. With ``refine_k > 0`` a second,
  local stage follows: for each joint, the k points nearest its first estimate vote again from
  their own features and their offset to that estimate (a cascade, as in hand-pose regressors
  from depth), which sharpens the far limbs that the global context places only roughly.
"""

from __future__ import annotations

import torch
from torch import nn

NUM_JOINTS = 22


def _conv(c_in: int, c_out: int) -> list[nn.Module]:
    """PointNet's shared MLP layer: 1x1 conv, BatchNorm, ReLU (BatchNorm as in Qi et al.)."""
    return [nn.Conv1d(c_in, c_out, 1), nn.BatchNorm1d(c_out), nn.ReLU()]


def _fc(c_in: int, c_out: int) -> list[nn.Module]:
    return [nn.Linear(c_in, c_out), nn.BatchNorm1d(c_out), nn.ReLU()]


class _STN(nn.Module):
    """PointNet's transform net: B x k x N -> B x k x k (initialised at the identity)."""

    def __init__(self, k: int):
        super().__init__()
        self.k = k
        self.conv = nn.Sequential(*_conv(k, 64), *_conv(64, 128), *_conv(128, 1024))
        self.fc = nn.Sequential(*_fc(1024, 512), *_fc(512, 256), nn.Linear(256, k * k))
        nn.init.zeros_(self.fc[-1].weight)
        nn.init.zeros_(self.fc[-1].bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        g = self.conv(x).amax(dim=2)
        eye = torch.eye(self.k, dtype=x.dtype, device=x.device).reshape(1, self.k * self.k)
        return (self.fc(g) + eye).reshape(-1, self.k, self.k)


class ReferencePointNet(nn.Module):
    """The published reference PointNet regressor. points B x N x 3 -> joints B x 22 x 3."""

    kind = "baseline"

    def __init__(self, num_joints: int = NUM_JOINTS):
        super().__init__()
        self.num_joints = num_joints
        self.stn3 = _STN(3)
        self.conv1 = nn.Sequential(*_conv(3, 64))
        self.stn64 = _STN(64)
        self.conv2 = nn.Sequential(*_conv(64, 128), *_conv(128, 1024))
        self.head = nn.Sequential(*_fc(1024, 512), *_fc(512, 256), nn.Dropout(0.3),
                                  nn.Linear(256, num_joints * 3))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        # The reference normalisation: centroid to the origin, largest |coordinate| to 1.
        centroid = points.mean(dim=1, keepdim=True)
        centred = points - centroid
        scale = centred.abs().amax(dim=(1, 2), keepdim=True).clamp_min(1e-6)
        x = (centred / scale).transpose(1, 2)  # B x 3 x N
        x = torch.bmm(self.stn3(x).transpose(1, 2), x)
        x = self.conv1(x)
        x = torch.bmm(self.stn64(x).transpose(1, 2), x)
        g = self.conv2(x).amax(dim=2)
        out = self.head(g).reshape(-1, self.num_joints, 3)
        return out * scale + centroid


class _PointLinear(nn.Module):
    """Linear + BatchNorm + ReLU applied to every point of a B x N x C tensor (the BatchNorm,
    over batch and points, is what makes these nets train in a few thousand steps; in eval mode
    it is a per-channel affine map that ONNX folds into the matmul)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.linear = nn.Linear(c_in, c_out, bias=False)
        self.norm = nn.BatchNorm1d(c_out)

    def forward(self, x: torch.Tensor, add: torch.Tensor | None = None) -> torch.Tensor:
        y = self.linear(x)
        if add is not None:
            y = y + add
        b, n, c = y.shape
        return torch.relu(self.norm(y.reshape(b * n, c)).reshape(b, n, c))


class _LocalRefine(nn.Module):
    """One cascade stage: each joint's ``k`` nearest points vote again for it, from their point
    features, their offset to the current estimate and a learned per-joint code."""

    def __init__(self, num_joints: int, width: int, refine_width: int, k: int):
        super().__init__()
        self.k = k
        self.feature = nn.Linear(width, refine_width)  # per point, before the gather (cheaper)
        self.offset = nn.Linear(3, refine_width, bias=False)
        self.joint_code = nn.Parameter(torch.zeros(num_joints, refine_width))
        self.mlp = nn.Sequential(nn.ReLU(), nn.Linear(refine_width, refine_width), nn.ReLU(),
                                 nn.Linear(refine_width, 4))

    def forward(self, points: torch.Tensor, f: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        b = points.shape[0]
        j, k = joints.shape[1], self.k
        dist = ((joints.unsqueeze(2) - points.unsqueeze(1)) ** 2).sum(-1)  # B x J x N
        idx = torch.topk(dist, k, dim=2, largest=False).indices.reshape(b, j * k)
        near = torch.gather(points, 1, idx.unsqueeze(-1).expand(b, j * k, 3)).reshape(b, j, k, 3)
        feat = self.feature(f)
        c = feat.shape[-1]
        feat = torch.gather(feat, 1, idx.unsqueeze(-1).expand(b, j * k, c)).reshape(b, j, k, c)
        h = feat + self.offset(near - joints.unsqueeze(2)) + self.joint_code.reshape(1, j, 1, c)
        out = self.mlp(h)  # B x J x K x 4
        weights = torch.softmax(out[..., 0], dim=2)
        votes = near + 0.25 * out[..., 1:]
        return (weights.unsqueeze(-1) * votes).sum(dim=2)


class VotingPointNet(nn.Module):
    """Our model: per-point votes for every joint. points B x N x 3 -> joints B x 22 x 3."""

    kind = "ours"

    def __init__(self, num_joints: int = NUM_JOINTS, width: int = 128, global_width: int = 256,
                 rounds: int = 2, refine_k: int = 0, refine_width: int = 64, refine_stages: int = 1):
        super().__init__()
        self.num_joints = num_joints
        self.local = nn.ModuleList([_PointLinear(3, 64), _PointLinear(64, width)])
        # Each round: a max-pooled global feature fed back to every point. The second round lets
        # the points see a context that already knows about the whole body (which way it faces).
        # Linear(concat(local, global)) is written as two Linears: the global part is computed
        # once per cloud instead of once per point.
        self.to_global = nn.ModuleList(_PointLinear(width, global_width) for _ in range(rounds))
        self.mix_global = nn.ModuleList(nn.Linear(global_width, width) for _ in range(rounds))
        self.mix = nn.ModuleList(_PointLinear(width, width) for _ in range(rounds))
        self.head = nn.Linear(width, num_joints * 4)
        self.refine = nn.ModuleList(_LocalRefine(num_joints, width, refine_width, refine_k)
                                    for _ in range(refine_stages if refine_k else 0))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.stages(points)[-1]

    def stages(self, points: torch.Tensor) -> list[torch.Tensor]:
        """The joints of every stage of the cascade, first estimate first (training supervises
        them all; the export keeps the last)."""
        b, n, _ = points.shape
        f = points
        for layer in self.local:
            f = layer(f)  # B x N x W
        for to_g, mix_g, mix in zip(self.to_global, self.mix_global, self.mix):
            g = to_g(f).amax(dim=1, keepdim=True)  # B x 1 x G
            f = mix(f, mix_g(g))
        out = self.head(f).reshape(b, n, self.num_joints, 4)
        weights = torch.softmax(out[..., 0], dim=1)  # over points: B x N x J
        votes = points.unsqueeze(2) + 0.5 * out[..., 1:]  # B x N x J x 3 (offsets ~metres)
        out = [(weights.unsqueeze(-1) * votes).sum(dim=1)]
        for stage in self.refine:
            out.append(stage(points, f, out[-1]))
        return out


def _bn_scale(bn: nn.BatchNorm1d) -> torch.Tensor:
    """Eval-mode BatchNorm is y * scale + (bias - mean * scale)."""
    return bn.weight / torch.sqrt(bn.running_var + bn.eps)


def _folded(layer: _PointLinear) -> tuple[torch.Tensor, torch.Tensor]:
    """(weight C_in x C_out, bias C_out) of Linear + eval-mode BatchNorm as one affine map."""
    scale = _bn_scale(layer.norm)
    return layer.linear.weight.t() * scale, layer.norm.bias - layer.norm.running_mean * scale


class DeployedVotingPointNet(nn.Module):
    """A trained ``VotingPointNet`` in the form that is exported: the same function (to float
    rounding), written for a small, fast ONNX graph. BatchNorm is folded into the matmuls; points
    are rows of one (B*N, C) matrix so every layer is one Gemm; the point count is a constant,
    so no shape arithmetic is traced; the refine stage's k-nearest search ranks |p|^2 - 2 j.p (one
    matmul, not a B x J x N x 3 difference) and gathers rows of the flattened features; the global
    features are computed channels-first so that their max over the points runs along contiguous
    rows (onnxruntime's ReduceMax over a middle axis was 6x slower). Half the nodes of the traced
    training graph, 0.6x its time (benchmarks/bench_skeleton.py)."""

    def __init__(self, net: VotingPointNet, num_points: int):
        super().__init__()
        if len(net.refine) > 1:
            raise ValueError("the deployed form handles one refine stage")
        self.n, self.j = int(num_points), net.num_joints
        with torch.no_grad():
            self.local = [_folded(layer) for layer in net.local]
            self.rounds = []
            for to_g, mix_g, mix in zip(net.to_global, net.mix_global, net.mix):
                w_mix, b_mix = _folded(mix)
                scale = _bn_scale(mix.norm)
                # BN(f W + g M + m) = f (W s) + g (M s) + (m s + t): the global term takes the scale.
                self.rounds.append((_folded(to_g), (mix_g.weight.t() * scale, mix_g.bias * scale + b_mix), w_mix))
            # head: per point and joint a weight logit and an offset, (w, o) = f H + h. The offset
            # part of the joint, sum_n softmax_n(w_nj) o_nj, is linear in f: (sum_n s_nj f_n) H_j + h_j.
            w_head = net.head.weight.reshape(self.j, 4, -1)  # J x 4 x W
            b_head = net.head.bias.reshape(self.j, 4)
            self.logit = (w_head[:, 0].t().clone(), b_head[:, 0].clone())  # W x J, J
            self.offset = (w_head[:, 1:].permute(0, 2, 1).clone(), b_head[:, 1:].clone())  # J x W x 3, J x 3
            self.refine = None
            if len(net.refine):
                r = net.refine[0]
                self.refine = dict(k=r.k, feature=(r.feature.weight.t().clone(), r.feature.bias.clone()),
                                   offset=r.offset.weight.t().clone(), code=r.joint_code.clone(),
                                   mlp1=(r.mlp[1].weight.t().clone(), r.mlp[1].bias.clone()),
                                   mlp2=(r.mlp[3].weight.t().clone(), r.mlp[3].bias.clone()))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        n, j = self.n, self.j
        p = points.reshape(-1, 3)  # (B*N, 3)
        f = p
        for w, b in self.local:
            f = torch.relu(torch.addmm(b, f, w))
        for (w_g, b_g), (w_mg, b_mg), w_mix in self.rounds:
            # channels-first (G, B*N): the max runs along contiguous rows
            gt = torch.relu(torch.addmm(b_g[:, None], w_g.t().contiguous(), f.t()))
            g = gt.reshape(w_g.shape[1], -1, n).amax(dim=2).t()  # B x G
            mixed = torch.addmm(b_mg, g, w_mg).unsqueeze(1)  # B x 1 x W
            f = torch.relu((f @ w_mix).reshape(-1, n, w_mix.shape[1]) + mixed).reshape(-1, w_mix.shape[1])
        weights = torch.softmax(torch.addmm(self.logit[1], f, self.logit[0]).reshape(-1, n, j), dim=1)  # B x N x J
        pts = points.reshape(-1, n, 3)
        pooled = weights.transpose(1, 2) @ torch.cat([pts, f.reshape(-1, n, f.shape[1])], dim=2)  # B x J x (3+W)
        offsets = (pooled[..., 3:].unsqueeze(2) @ self.offset[0]).squeeze(2) + self.offset[1]  # B x J x 3
        joints = pooled[..., :3] + 0.5 * offsets
        if self.refine is None:
            return joints
        r = self.refine
        k = r["k"]
        # k nearest points of each joint: rank |p|^2 - 2 j.p (|j|^2 is the same along a row).
        rank = (pts * pts).sum(-1).unsqueeze(1) - 2.0 * (joints @ pts.transpose(1, 2))  # B x J x N
        idx = torch.topk(rank, k, dim=2, largest=False).indices  # B x J x K
        rows = (idx + (torch.arange(idx.shape[0]) * n).reshape(-1, 1, 1)).reshape(-1)
        feat = torch.addmm(r["feature"][1], f, r["feature"][0]) + p @ r["offset"]  # (B*N, R)
        near = p[rows].reshape(-1, j, k, 3)
        # feature + offset(near - joint) + code = gathered (feature + offset(p)) - offset(joint) + code
        h = feat[rows].reshape(-1, j, k, feat.shape[1]) + (r["code"] - joints @ r["offset"]).unsqueeze(2)
        h = torch.relu(torch.relu(h) @ r["mlp1"][0] + r["mlp1"][1])
        out = h @ r["mlp2"][0] + r["mlp2"][1]  # B x J x K x 4
        w = torch.softmax(out[..., 0], dim=2)
        return ((near + 0.25 * out[..., 1:]) * w.unsqueeze(-1)).sum(dim=2)


MODELS = {"ours": VotingPointNet, "baseline": ReferencePointNet}


def build(kind: str, **options) -> nn.Module:
    """A fresh network by kind ("ours" or "baseline"); ``options`` go to its constructor."""
    if kind not in MODELS:
        raise ValueError(f"unknown model kind {kind!r}; choose from {', '.join(MODELS)}")
    return MODELS[kind](**options)


def count_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def export_onnx(model: nn.Module, path: str, num_points: int, opset: int = 17) -> None:
    """Write ``model`` (eval mode) as ONNX: input "points" (B, N, 3) float32, output "joints"
    (B, 22, 3); the batch is dynamic. ``VotingPointNet`` goes out in its deployed form
    (``DeployedVotingPointNet``, N fixed at ``num_points``); the reference keeps its own graph
    (dynamic N), as published."""
    model = model.eval()
    if isinstance(model, VotingPointNet):
        export_deployed(DeployedVotingPointNet(model, num_points), path, opset)
        return
    axes = {"points": {0: "batch", 1: "num_points"}, "joints": {0: "batch"}}
    torch.onnx.export(model, (_example(num_points),), path, input_names=["points"], output_names=["joints"],
                      dynamic_axes=axes, opset_version=opset, dynamo=False)


def export_deployed(deployed: DeployedVotingPointNet, path: str, opset: int = 17) -> None:
    """The ONNX graph of a deployed net (also what models.train.reexport_skeleton traces to find
    which graph constant holds which weight, so both must come from here)."""
    torch.onnx.export(deployed.eval(), (_example(deployed.n),), path, input_names=["points"], output_names=["joints"],
                      dynamic_axes={"points": {0: "batch"}, "joints": {0: "batch"}}, opset_version=opset, dynamo=False)


def _example(num_points: int) -> torch.Tensor:
    example = torch.zeros(1, num_points, 3)
    example[0, :, 1] = torch.linspace(0.0, 1.7, num_points)
    return example
