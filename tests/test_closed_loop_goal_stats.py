"""The statistics of ``benchmarks.closed_loop --goal`` (issue 15, goal 1): what an exact predictor
leaves outside the Wilson intervals, the two-sample test, Holm's step-down, the pooled seeds."""

from __future__ import annotations

import numpy as np
from benchmarks.closed_loop import (
    calibration,
    holm,
    outside_probability,
    poisson_binomial_tail,
    pooled,
    two_sample_p,
)


def test_an_exact_prediction_falls_outside_about_one_wilson_interval_in_twenty():
    assert outside_probability(0.0, 1000) == 0.0  # k = 0 always covers 0
    assert 0.03 < outside_probability(0.05, 1000) < 0.07
    # A rare rate: outside as soon as two runs of 1000 break it (P = 1 - e^-0.2 (1.2) ~ 0.0175).
    assert abs(outside_probability(0.0002, 1000) - 0.0175) < 0.001
    # Checked by simulation at one rate.
    rng = np.random.default_rng(0)
    from idstlpy.execution import wilson_interval

    hits = rng.binomial(1000, 0.02, size=4000)
    sim = np.mean([not (lo <= 0.02 <= hi) for lo, hi in (wilson_interval(int(k), 1000) for k in hits)])
    assert abs(sim - outside_probability(0.02, 1000)) < 0.01


def test_two_sample_p_holm_and_the_poisson_binomial_tail():
    # 3 of 1000 against 4 of 20000: outside the one-sample interval, and a two-sample p of 0.003.
    assert 0.002 < two_sample_p(4 / 20000, 20000, 3 / 1000, 1000) < 0.005
    assert two_sample_p(0.05, 20000, 0.05, 1000) > 0.9
    assert holm([0.001, 0.04, 0.5]) == [True, False, False]  # 0.04 > 0.05 / 2
    assert holm([0.01, 0.02]) == [True, True]  # 0.01 <= 0.025, then 0.02 <= 0.05
    assert poisson_binomial_tail([0.5, 0.5], 1) == 0.75
    assert abs(poisson_binomial_tail([0.05] * 300, 15) - 0.537) < 0.01


def _row(case: str, seed: int, measured: float, outside: bool) -> dict:
    entry = {
        "group": "predicates",
        "name": "f",
        "reading": "state",
        "predicted": 0.02,
        "measured": measured,
        "outside": outside,
    }
    return {"case": case, "seed": seed, "runs": 1000, "samples": 20000, "entries": [entry]}


def test_calibration_per_seed_and_pooled_seeds():
    rows = [_row("p [seed 0]", 0, 0.031, True), _row("p [seed 1]", 1, 0.029, False)]
    cal = calibration(rows)
    assert [t["seed"] for t in cal["totals"]] == [0, 1]
    assert [t["outside"] for t in cal["totals"]] == [1, 0]
    ((a,),) = [pooled(rows)]
    assert (a["case"], a["hits"], a["runs"], a["seeds_outside"]) == ("p", 60, 2000, 1)
    assert a["p_two"] < rows[0]["entries"][0]["p_two"]  # two seeds in the same direction: stronger
