"""Learned online retargeting network (torch, training only; the runtime runs its ONNX export).

After Villegas et al.'s neural kinematic networks, sized for a 2-core CPU:

- encoder: a 2-layer GRU over per-frame source features (``source_features``): the source joints
  relative to the pelvis, the root velocity and the pelvis height (all in units of the source's
  leg length L_s = rest pelvis height), plus the source's own T-pose (also / L_s);
- decoder: a 1-layer GRU over [encoding, target T-pose / L_t], then a linear head to per-joint 6D
  rotations (a residual on the identity) and a root correction (in units of L_t) added to the
  leg-length-scaled source root;
- a differentiable FK layer (``fk``) gives the target joints from the rotations and its T-pose.

Scaling every length by the leg length makes a child and an adult the same problem. Shapes:
B x T x 22 x 3 joints, B x T x 22 x 3 x 3 rotation matrices; the step module used for export
takes one frame and the hidden states as explicit inputs and outputs.
"""

from __future__ import annotations

import torch
from torch import nn

from live.core import skeleton

NUM_JOINTS = skeleton.NUM_JOINTS
PARENTS = tuple(int(p) for p in skeleton.PARENTS)  # plain ints, for indexing tensors
SOURCE_FEATURES = 22 * 3 + 21 * 3 + 3 + 1 + 22 * 3  # pose, bone directions, root velocity, height, T-pose
TARGET_FEATURES = 22 * 3
_IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)  # first two columns of the identity


def leg_length(rest: torch.Tensor) -> torch.Tensor:
    """... x 22 x 3 T-poses -> ... x 1 x 1 pelvis heights (the leg length)."""
    return rest[..., :1, 1:2].clamp_min(1e-3)


def rest_features(rest: torch.Tensor) -> torch.Tensor:
    """B x 22 x 3 T-poses -> B x 66: joints relative to the pelvis, / leg length."""
    return ((rest - rest[:, :1]) / leg_length(rest)).flatten(1)


def source_features(joints: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    """B x T x 22 x 3 world source joints and their B x 22 x 3 T-pose -> B x T x SOURCE_FEATURES.

    Unit bone directions are given besides the positions: they are what rotations are made of, so
    the network need not learn to normalise. The root velocity of frame 0 is zero (as online,
    where there is no previous frame)."""
    scale = leg_length(rest)[:, None]  # B x 1 x 1 x 1
    root = joints[:, :, :1]
    pose = ((joints - root) / scale).flatten(2)
    bones = joints[:, :, 1:] - joints[:, :, list(PARENTS[1:])]
    dirs = (bones / bones.norm(dim=-1, keepdim=True).clamp_min(1e-6)).flatten(2)
    vel = torch.diff(root[:, :, 0], dim=1, prepend=root[:, :1, 0]) / scale[:, :, 0]
    height = root[:, :, 0, 1:2] / scale[:, :, 0]
    rest_f = rest_features(rest)[:, None].expand(-1, joints.shape[1], -1)
    return torch.cat([pose, dirs, vel, height, rest_f], dim=-1)


def sixd_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """... x 6 -> ... x 3 x 3 (columns x, y, z) by Gram-Schmidt, as live.core.rotations."""
    a, b = d6[..., :3], d6[..., 3:]
    x = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    b = b - (x * b).sum(-1, keepdim=True) * x
    y = b / b.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    z = torch.cross(x, y, dim=-1)
    return torch.stack([x, y, z], dim=-1)


def global_to_local(glob: torch.Tensor) -> torch.Tensor:
    """Global rotations ... x 22 x 3 x 3 -> local (relative to the parent) rotations."""
    parent = glob[..., [max(p, 0) for p in PARENTS], :, :]
    local = parent.transpose(-1, -2) @ glob
    return torch.cat([glob[..., :1, :, :], local[..., 1:, :, :]], dim=-3)


def fk(local: torch.Tensor, root: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    """Differentiable FK: local rotations B x T x 22 x 3 x 3, root B x T x 3, T-poses B x 22 x 3
    -> world joints B x T x 22 x 3 (same result as live.core.kinematics.forward_kinematics)."""
    offsets = rest - rest[:, [max(p, 0) for p in PARENTS]]
    glob = [local[:, :, 0]]
    pos = [root]
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        pos.append(pos[p] + torch.einsum("btij,bj->bti", glob[p], offsets[:, j]))
        glob.append(glob[p] @ local[:, :, j])
    return torch.stack(pos, dim=2)


class RetargetNet(nn.Module):
    """Encoder GRU (2 layers) + decoder GRU (1 layer) + linear head; ``hidden`` units each."""

    def __init__(self, hidden: int = 192, enc_layers: int = 2, dec_layers: int = 1):
        super().__init__()
        self.hidden, self.enc_layers, self.dec_layers = hidden, enc_layers, dec_layers
        self.inp = nn.Sequential(nn.Linear(SOURCE_FEATURES, hidden), nn.GELU())
        self.encoder = nn.GRU(hidden, hidden, enc_layers, batch_first=True)
        self.target = nn.Sequential(nn.Linear(TARGET_FEATURES, hidden), nn.GELU())
        self.decoder = nn.GRU(2 * hidden, hidden, dec_layers, batch_first=True)
        self.head = nn.Sequential(nn.Linear(2 * hidden, hidden), nn.GELU(), nn.Linear(hidden, NUM_JOINTS * 6 + 3))
        nn.init.zeros_(self.head[-1].weight)
        nn.init.zeros_(self.head[-1].bias)
        self.register_buffer("identity6", torch.tensor(_IDENTITY_6D).repeat(NUM_JOINTS))

    def forward(self, src_feat: torch.Tensor, tgt_feat: torch.Tensor, h_enc: torch.Tensor | None = None,
                h_dec: torch.Tensor | None = None):
        """src_feat B x T x SOURCE_FEATURES, tgt_feat B x TARGET_FEATURES -> (global rotations as
        6D B x T x 22 x 6 (the world rotation of each joint; local = parent^T global),
        root correction B x T x 3 in target leg lengths, h_enc, h_dec)."""
        enc, h_enc = self.encoder(self.inp(src_feat), h_enc)
        tgt = self.target(tgt_feat)[:, None].expand(-1, enc.shape[1], -1)
        dec, h_dec = self.decoder(torch.cat([enc, tgt], dim=-1), h_dec)
        out = self.head(torch.cat([dec, enc], dim=-1))
        d6 = (out[..., :NUM_JOINTS * 6] + self.identity6).unflatten(-1, (NUM_JOINTS, 6))
        return d6, out[..., NUM_JOINTS * 6:], h_enc, h_dec

    def retarget(self, src_joints: torch.Tensor, src_rest: torch.Tensor, tgt_rest: torch.Tensor):
        """Whole windows: B x T x 22 x 3 source joints on B x 22 x 3 source T-poses, onto target
        T-poses -> (local rotations B x T x 22 x 3 x 3, root B x T x 3, joints B x T x 22 x 3)."""
        d6, droot, _, _ = self(source_features(src_joints, src_rest), rest_features(tgt_rest))
        # Global rotations out, local ones derived: each observed bone direction maps to a world
        # rotation directly, which is far easier to learn than the chain of local ones.
        rot = global_to_local(sixd_to_matrix(d6))
        ratio = leg_length(tgt_rest) / leg_length(src_rest)  # B x 1 x 1
        root = src_joints[:, :, 0] * ratio + droot * leg_length(tgt_rest)
        return rot, root, fk(rot, root, tgt_rest)


class StepModule(nn.Module):
    """One frame, hidden states explicit (what the ONNX file contains).

    inputs: source (1, SOURCE_FEATURES), target (1, TARGET_FEATURES), h_enc (enc_layers, 1, H),
    h_dec (dec_layers, 1, H); outputs: rot6d (1, 22, 6) global rotations, root_delta (1, 3),
    h_enc_out, h_dec_out."""

    def __init__(self, net: RetargetNet):
        super().__init__()
        self.net = net

    def forward(self, source, target, h_enc, h_dec):
        d6, droot, h_enc, h_dec = self.net(source[:, None], target, h_enc, h_dec)
        return d6[:, 0], droot[:, 0], h_enc, h_dec


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def export_onnx(net: RetargetNet, path: str, opset: int = 17) -> None:
    """Write the step module as ONNX with the recurrent state as explicit inputs/outputs."""
    step = StepModule(net.eval())
    h = net.hidden
    args = (torch.zeros(1, SOURCE_FEATURES), torch.zeros(1, TARGET_FEATURES),
            torch.zeros(net.enc_layers, 1, h), torch.zeros(net.dec_layers, 1, h))
    torch.onnx.export(step, args, path, input_names=["source", "target", "h_enc", "h_dec"],
                      output_names=["rot6d", "root_delta", "h_enc_out", "h_dec_out"],
                      opset_version=opset, dynamo=False)


# ------------------------------------------------------------------------------- skinning field
class SkinningField(nn.Module):
    """The skinning field: for points N x 3 of a body in T-pose and its T-pose joints 22 x 3,
    distances to the joints / leg length -> 3-layer MLP -> softmax -> weights N x 22."""

    def __init__(self, hidden: int = 128):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(NUM_JOINTS, hidden), nn.GELU(), nn.Linear(hidden, hidden), nn.GELU(),
                                 nn.Linear(hidden, NUM_JOINTS))

    def logits(self, points: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        d = torch.linalg.norm(points[:, None, :] - joints[None], dim=-1) / joints[0, 1].clamp_min(1e-3)
        return self.mlp(d)

    def forward(self, points: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        return torch.softmax(self.logits(points, joints), dim=-1)


def export_skinning_onnx(field: SkinningField, path: str, opset: int = 17) -> None:
    """ONNX: inputs "points" (N, 3), "joints" (22, 3) float32 -> "weights" (N, 22); N dynamic."""
    pts = torch.rand(64, 3)
    joints = torch.rand(NUM_JOINTS, 3) + torch.tensor([0.0, 1.0, 0.0])
    torch.onnx.export(field.eval(), (pts, joints), path, input_names=["points", "joints"], output_names=["weights"],
                      dynamic_axes={"points": {0: "n"}, "weights": {0: "n"}}, opset_version=opset, dynamo=False)
