"""Skeleton regression networks (torch, training only; the runtime runs their ONNX export).

Both take person-frame points B x N x 3 (metres, see models.skeleton.preprocess) and return
person-frame joints B x 22 x 3, so that the runtime, the evaluation and the export treat them
the same way.

- ``ReferencePointNet``: the published baseline as described in issue 4: input centred on its
  centroid and scaled into the unit cube, input STN (k=3), conv 3->64, feature STN (k=64),
  conv 64->128->1024, max-pool, FC 1024->512->256 (dropout 0.3) -> 66, ReLU; the normalisation
  is undone on the output; BatchNorm after every layer but the last, as in the original
  PointNet. 3.5 M parameters with the feature STN (the issue's "about 1.6 M" is the count
  without it; see docs/skeleton.md).
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
    """The reference PointNet regressor (issue 4). points B x N x 3 -> joints B x 22 x 3."""

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
    (B, 22, 3); batch and point count are dynamic."""
    model = model.eval()
    example = torch.zeros(1, num_points, 3)
    example[0, :, 1] = torch.linspace(0.0, 1.7, num_points)
    torch.onnx.export(model, (example,), path, input_names=["points"], output_names=["joints"],
                      dynamic_axes={"points": {0: "batch", 1: "num_points"}, "joints": {0: "batch"}},
                      opset_version=opset, dynamo=False)
