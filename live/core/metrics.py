"""Evaluation metrics for skeletons and meshes, float64, pure numpy (+ one cKDTree for MDEL).

Shapes: joints / vertices T x N x 3 in metres (a single frame N x 3 also works). Every metric
returns metres (metres per frame^2 for the acceleration errors) as a Python float averaged over
frames and points, except ``per_joint_mpjpe`` (N,). Reports give them in mm and mm/frame^2, the
unit in the key (``mpjpe_mm``, ``acc_mm_per_frame2``).

* MPJPE: mean Euclidean distance between corresponding joints.
* PA-MPJPE: MPJPE after aligning each predicted frame to the ground truth with the best
  similarity transform (rotation, uniform scale, translation; Umeyama / orthogonal Procrustes).
* PCK: fraction of joints closer than ``threshold`` metres.
* Turned share: fraction of frames whose body faces more than ``degrees`` away from the truth's
  (the horizontal direction across hips and shoulders; 22-joint skeletons): a body read facing
  away, a frame no joint alignment repairs.
* Acc error: mean norm of the difference of the second finite differences of pred and gt, in
  metres per frame^2 at the motion's own frame rate (the unit of papers that report "Acc"
  without a frame rate).
* MPVD / PA-MPVD: MPJPE / PA-MPJPE over mesh vertices.
* MDEL: mean absolute change of the lengths of the edges from each point to its k nearest
  neighbours, the neighbours found once on the reference (rest / T-pose) point set.
"""

from __future__ import annotations

import numpy as np

from live.core.errors import UserInputError
from live.core.heading import body_heading, wrap_angle


def _pair(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.ndim < 2 or pred.shape[-1] != 3:
        raise UserInputError(f"pred and gt must both be (T, N, 3), got {pred.shape} and {gt.shape}")
    if pred.ndim == 2:
        pred, gt = pred[None], gt[None]
    return pred.reshape(-1, *pred.shape[-2:]), gt.reshape(-1, *gt.shape[-2:])


def mpjpe(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean per-joint position error (m) of T x J x 3 predictions against T x J x 3 truth."""
    pred, gt = _pair(pred, gt)
    return float(np.linalg.norm(pred - gt, axis=-1).mean())


def per_joint_mpjpe(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Position error (m) of each joint, averaged over frames: T x J x 3 -> (J,)."""
    pred, gt = _pair(pred, gt)
    return np.linalg.norm(pred - gt, axis=-1).mean(axis=0)


def procrustes_align(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Each frame of pred (T x N x 3) moved by its best similarity transform onto gt (T x N x 3).

    Least-squares rotation (no reflection), uniform scale and translation (Umeyama 1991),
    vectorised over frames. Returns the aligned T x N x 3.
    """
    pred, gt = _pair(pred, gt)
    mu_p = pred.mean(axis=1, keepdims=True)
    mu_g = gt.mean(axis=1, keepdims=True)
    p = pred - mu_p
    g = gt - mu_g
    cov = np.einsum("tni,tnj->tij", g, p)  # sum over points of g p^T
    u, s, vt = np.linalg.svd(cov)
    # Force a proper rotation: flip the smallest singular direction when det < 0.
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    s[:, -1] *= d
    u[:, :, -1] *= d[:, None]
    rot = u @ vt
    var_p = np.sum(p * p, axis=(1, 2))
    scale = s.sum(axis=1) / np.maximum(var_p, 1e-300)
    return scale[:, None, None] * np.einsum("tij,tnj->tni", rot, p) + mu_g


def pa_mpjpe(pred: np.ndarray, gt: np.ndarray) -> float:
    """MPJPE (m) after per-frame Procrustes alignment (rotation, scale, translation) of pred."""
    pred, gt = _pair(pred, gt)
    return mpjpe(procrustes_align(pred, gt), gt)


def pck(pred: np.ndarray, gt: np.ndarray, threshold: float = 0.1) -> float:
    """Fraction in [0, 1] of joints (over all frames) within ``threshold`` metres of the truth."""
    pred, gt = _pair(pred, gt)
    return float((np.linalg.norm(pred - gt, axis=-1) < threshold).mean())


def turned_share(pred: np.ndarray, gt: np.ndarray, degrees: float = 45.0) -> float:
    """Fraction in [0, 1] of frames whose body is turned more than ``degrees`` about the vertical
    from the truth's (``live.core.heading.body_heading``), 22-joint skeletons (T x 22 x 3, y up)."""
    pred, gt = _pair(pred, gt)
    return float(turned(pred, gt, degrees).mean())


def turned(pred: np.ndarray, gt: np.ndarray, degrees: float = 45.0) -> np.ndarray:
    """(...,) bool: bodies (..., 22, 3) turned more than ``degrees`` about the vertical from the
    truth's (False where either is NaN)."""
    return np.abs(wrap_angle(body_heading(pred) - body_heading(gt))) > np.radians(degrees)


def acceleration_error(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean norm (m/frame^2) of (second difference of pred - that of gt) over T-2 frames and J
    joints. Needs T >= 3.
    """
    pred, gt = _pair(pred, gt)
    if len(pred) < 3:
        raise UserInputError("acceleration error needs at least 3 frames")
    acc = (pred[2:] - 2.0 * pred[1:-1] + pred[:-2]) - (gt[2:] - 2.0 * gt[1:-1] + gt[:-2])
    return float(np.linalg.norm(acc, axis=-1).mean())


def pa_acceleration_error(pred: np.ndarray, gt: np.ndarray) -> float:
    """``acceleration_error`` (m/frame^2) after per-frame Procrustes alignment of pred onto gt."""
    pred, gt = _pair(pred, gt)
    return acceleration_error(procrustes_align(pred, gt), gt)


def mpvd(pred_vertices: np.ndarray, gt_vertices: np.ndarray) -> float:
    """Mean per-vertex distance (m) of T x V x 3 meshes with the same topology."""
    return mpjpe(pred_vertices, gt_vertices)


def pa_mpvd(pred_vertices: np.ndarray, gt_vertices: np.ndarray) -> float:
    """MPVD (m) after per-frame Procrustes alignment of the predicted vertices."""
    return pa_mpjpe(pred_vertices, gt_vertices)


def knn_edges(reference: np.ndarray, k: int = 6) -> np.ndarray:
    """(V, k) indices of each reference point's k nearest other points (one cKDTree query)."""
    from scipy.spatial import cKDTree

    ref = np.asarray(reference, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3 or len(ref) <= k:
        raise UserInputError(f"reference must be (V, 3) with V > k={k}, got {ref.shape}")
    _, idx = cKDTree(ref).query(ref, k=k + 1)
    return idx[:, 1:]  # drop the point itself


def mdel(pred_vertices: np.ndarray, reference: np.ndarray, k: int = 6, edges: np.ndarray | None = None) -> float:
    """Mean absolute edge-length change (m) of T x V x 3 points against a reference.

    reference: V x 3 rest (T-pose) points, whose edge lengths every frame is compared with; or
    T x V x 3 ground-truth points, compared frame by frame. Edges join each point to its k nearest
    neighbours, found once (cKDTree) in the V x 3 reference or in the first ground-truth frame
    (pass the T-pose's ``knn_edges`` as ``edges`` to use those instead, or to reuse them).
    """
    pred = np.asarray(pred_vertices, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if pred.ndim == 2:
        pred = pred[None]
    if pred.ndim != 3 or ref.shape not in (pred.shape, pred.shape[1:]):
        raise UserInputError(f"pred (T, V, 3) and reference (V, 3) or (T, V, 3) disagree: {pred.shape} vs {ref.shape}")
    nbr = knn_edges(ref if ref.ndim == 2 else ref[0], k) if edges is None else np.asarray(edges)
    ref_len = np.linalg.norm(ref[..., nbr, :] - ref[..., :, None, :], axis=-1)  # ([T,] V, k)
    pred_len = np.linalg.norm(pred[:, nbr] - pred[:, :, None, :], axis=-1)  # (T, V, k)
    return float(np.abs(pred_len - ref_len).mean())
