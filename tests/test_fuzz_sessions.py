"""Fuzzing session files through the commands that read them: a 1 s synthetic session (depth,
ground truth, an Xbus suit, the embedded body) damaged by seeded random and structured
mutations (MCAP opcodes, record lengths, chunk sizes and CRCs, cuts), each through ``info
--json``, ``replay --speed max`` and, for some, ``export`` (research/fuzz_inputs.py).

Judged as in test_fuzz_inputs.py; on top, exit 0 means every message and frame of the intact
session was read. Kept apart from the other formats so the session reader's own work can mark
cases here (KNOWN_FAILURES) without touching the rest.
"""

from __future__ import annotations

import pytest

from research.fuzz_inputs import FAILURES, fuzz_case, shared_bases

SEED = 27
CASES = 12
#: {case: why} known to fail; xfail (strict), so each is reported by name until it passes.
KNOWN_FAILURES: dict[int, str] = {}


@pytest.fixture(scope="module")
def bases(shared_bvh):
    return shared_bases(shared_bvh / "mb_12_01.bvh")


#: Cases the long run (``python -m research.fuzz_inputs``, seed 0) once failed, kept: (seed, case, what it was).
REGRESSIONS = [(0, 68, "a channel record's opcode damaged: the summary counts a channel it lacks (KeyError)"),
               (1, 62, "a message index record whose opcode became 0x05 (message) after the last chunk")]
#: {(seed, case): why} of REGRESSIONS not fixed yet (xfail, strict).
KNOWN_REGRESSIONS: dict[tuple[int, int], str] = {}


def _params():
    for k in range(CASES):
        marks = [pytest.mark.xfail(reason=KNOWN_FAILURES[k], strict=True)] if k in KNOWN_FAILURES else []
        yield pytest.param(SEED, k, id=str(k), marks=marks)
    for seed, k, _ in REGRESSIONS:
        why = KNOWN_REGRESSIONS.get((seed, k))
        marks = [pytest.mark.xfail(reason=why, strict=True)] if why else []
        yield pytest.param(seed, k, id=f"seed{seed}-{k}", marks=marks)


@pytest.mark.parametrize("seed, case", list(_params()))
def test_a_damaged_session_is_read_around_or_refused(seed, case, bases):
    results = fuzz_case(bases, "session", case, seed)
    assert {r.command for r in results} >= {"info", "replay"}
    bad = [f"{r.command}: {r.mutation}: {r.outcome}: {r.detail}" for r in results if r.outcome in FAILURES]
    assert not bad, "\n".join(bad)
