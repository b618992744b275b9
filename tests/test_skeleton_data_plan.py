"""The training plan of the skeleton regressor: held-out splits, on-demand Anny phenotypes."""

from __future__ import annotations

import numpy as np

from live.body.library import ANNY_KEYS, format_anny_spec, list_presets, parse_anny_spec, preset_phenotypes
from sim.skeleton_data import ANNY_HOLD_OUT_MARGIN, ANNY_RANGES, VAL_SUBJECTS, anny_phenotypes, plan_jobs, split_bodies


def test_anny_phenotypes_are_deterministic_people_away_from_the_held_out_bodies():
    specs = anny_phenotypes(200, seed=3)
    assert specs == anny_phenotypes(200, seed=3) and specs != anny_phenotypes(200, seed=4)
    assert len(set(specs)) == len(specs)
    phenotypes = preset_phenotypes()
    held_out = [phenotypes[n] for n in split_bodies(list_presets(), "val")]
    for spec in specs:
        ph = parse_anny_spec(spec)  # a valid body spec, in its canonical form
        assert format_anny_spec(ph) == spec
        assert all(ANNY_RANGES[k][0] <= ph[k] <= ANNY_RANGES[k][1] for k in ANNY_KEYS)
        for h in held_out:
            assert max(abs(ph[k] - h[k]) for k in ANNY_KEYS) >= ANNY_HOLD_OUT_MARGIN


def test_plan_mixes_anny_bodies_into_training_only():
    pool = anny_phenotypes(16)
    plain = plan_jobs("train", 4000, seed=0)
    mixed = plan_jobs("train", 4000, seed=0, anny=pool, anny_share=0.3)
    share = np.mean([j.body.startswith("anny:") for j in mixed])
    assert 0.25 < share < 0.35
    assert not any(j.body.startswith("anny:") for j in plain)
    assert {j.body for j in mixed if not j.body.startswith("anny:")} <= set(split_bodies(list_presets(), "train"))
    val = plan_jobs("val", 400, seed=1, anny=pool, anny_share=0.3)
    assert all(j.body in split_bodies(list_presets(), "val") and j.subject in VAL_SUBJECTS for j in val)


def test_hard_views_weight_training_only_and_leave_the_usual_plan_unchanged():
    from sim.sensor_realism import HARD_VIEWS, USUAL_VIEWS, random_posture

    usual = plan_jobs("train", 4000, seed=0, realism=True)
    assert usual == plan_jobs("train", 4000, seed=0, realism=True, hard_share=0.0)
    hard = plan_jobs("train", 4000, seed=0, realism=True, hard_share=0.5)
    share = np.mean([j.hard_views for j in hard])
    assert 0.4 < share < 0.6 and not any(j.hard_views for j in usual)
    closeups = [np.mean([j.closeup for j in hard if j.hard_views == h]) for h in (False, True)]
    assert closeups[1] > 1.5 * closeups[0]
    assert not any(j.hard_views for j in plan_jobs("val_real", 400, seed=3, hard_share=0.5))
    rng = np.random.default_rng(0)
    seated = [np.mean([random_posture(rng, odds) == "seated" for _ in range(4000)]) for odds in (USUAL_VIEWS, HARD_VIEWS)]
    assert abs(seated[0] - USUAL_VIEWS.posture["seated"]) < 0.02 and abs(seated[1] - HARD_VIEWS.posture["seated"]) < 0.03


def test_raised_legs_are_drawn_for_realism_training_only_and_leave_the_usual_plan_unchanged():
    usual = plan_jobs("train", 4000, seed=0, realism=True)
    raised = plan_jobs("train", 4000, seed=0, realism=True, knee_up_share=0.2)
    share = np.mean([j.posture == "knee-up" for j in raised])
    assert 0.15 < share < 0.25 and not any(j.posture for j in usual)
    # The same jobs otherwise: the raised legs are drawn from a stream of their own.
    assert [(j.clip, j.body, j.camera, j.closeup) for j in raised] == [(j.clip, j.body, j.camera, j.closeup)
                                                                        for j in usual]
    # Kicks take the draws above the knee raises': the knee-up jobs stay the same jobs.
    kicks = plan_jobs("train", 4000, seed=0, realism=True, knee_up_share=0.2, kick_share=0.1)
    assert [j.posture == "knee-up" for j in kicks] == [j.posture == "knee-up" for j in raised]
    assert 0.07 < np.mean([j.posture == "kick" for j in kicks]) < 0.13
    assert not any(j.posture for j in plan_jobs("val_real", 400, seed=3, knee_up_share=0.5, kick_share=0.5))
    assert not any(j.posture for j in plan_jobs("train", 400, seed=0, knee_up_share=0.5))  # no realism
