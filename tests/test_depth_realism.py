"""The depth-realism statistics on synthetic frames with known holes, noise and edges."""

import numpy as np

from research.depth_realism import (
    PROFILE_REACH,
    edge_profiles,
    hole_ratios,
    neighbour_gradients,
    plane_residuals,
    profile_summary,
    quantisation_step,
    silhouette,
)


def _scene(noise_mm: float = 0.0, seed: int = 0):
    """A 60x40 px body at 2000 mm (a tilted plane) on a background at 3000 mm."""
    rng = np.random.default_rng(seed)
    depth = np.full((120, 120), 3000.0)
    v, u = np.mgrid[0:120, 0:120]
    body = (v >= 30) & (v < 90) & (u >= 40) & (u < 80)
    depth[body] = 2000.0 + 2.0 * (u[body] - 40) + rng.normal(0.0, noise_mm, body.sum()) if noise_mm else \
        2000.0 + 2.0 * (u[body] - 40)
    return depth, body


def test_hole_ratios_count_holes_on_body_and_bands():
    depth, body = _scene()
    depth = np.rint(depth).astype(np.uint16)
    depth[50:60, 50:60] = 0  # 100 interior holes
    depth[30:90, 78] = 0  # a hole line one column inside the right edge: inner band
    depth[30:90, 80:82] = 0  # a 2 px shadow right of the body
    person = body & (depth > 0)
    sil = silhouette(person)
    assert (sil == body).mean() > 0.99
    r = hole_ratios(depth, person, sil, band_px=2)
    assert abs(r["body"] - (100 + 60) / body.sum()) < 0.005
    # Inner band: 2 px ring inside the 60x40 box, one of its four sides all holes.
    ring = body.sum() - (56 * 36)
    assert abs(r["inner_band"] - 60 / ring) < 0.02
    outer = (64 * 44) - body.sum()
    assert abs(r["outer_band"] - 120 / outer) < 0.02


def test_gradients_and_plane_residuals_recover_slope_and_noise():
    depth, body = _scene()
    g = neighbour_gradients(np.rint(depth).astype(np.uint16), body)
    # Horizontal pairs step 2 mm, vertical pairs 0 mm.
    assert set(np.unique(g)) == {0.0, 2.0}
    z, res = plane_residuals(np.rint(depth).astype(np.uint16), body)
    assert len(z) == 56 * 36 and np.allclose(z, 2.0, atol=0.1) and res.max() < 0.5
    noisy, _ = _scene(noise_mm=10.0, seed=1)
    _, res = plane_residuals(np.clip(np.rint(noisy), 1, None).astype(np.uint16), body)
    assert 8.0 < np.median(res) < 11.0  # a 5x5 fit leaves (22/25) of the variance


def test_edge_profiles_find_holes_and_flying_pixels():
    depth, body = _scene()
    depth = np.rint(depth).astype(np.uint16)
    depth[30:90, 80] = 0  # a hole just outside the right edge
    depth[30:90, 39] = 2500  # a flying pixel just outside the left edge
    sil = silhouette(body & (depth > 0))
    prof, sides = edge_profiles(depth, sil)
    assert len(prof) == 120 and (sides == 1).sum() == 60
    s = profile_summary(prof, sides)
    assert s["holes_per_right_edge"] == 1.0 and s["holes_per_left_edge"] == 0.0
    assert s["flying_per_edge"] == 0.5
    assert s["hole"][PROFILE_REACH] == 0.5 and s["hole"][PROFILE_REACH - 1] == 0.0


def test_quantisation_step_of_levels():
    values = (3000 + 26 * np.random.default_rng(0).integers(0, 8, 500)).astype(np.uint16)
    assert quantisation_step(values) == 26.0
    assert quantisation_step(np.arange(2000, 2100).astype(np.uint16)) == 1.0
