"""The command line's progress line shows the solver's counters (issue 34, budgets)."""

from __future__ import annotations

import io
import logging
import re

import numpy as np

import idstlpy as stl
from idstlpy.cli.progress import Ticker
from idstlpy.scenarios import light_dark


def _line(goal: float) -> stl.Problem:
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float, name="u")
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.0]])
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        stl.eventually(
            0,
            40,
            stl.logical_and(stl.prob(x[0] >= goal) >= 0.9, stl.prob(x[0] <= goal + 1) >= 0.9, name="goal"),
        ),
    )


def test_the_line_counts_candidates_refutations_and_the_length():
    ticker = Ticker(io.StringIO(), enabled=True)
    ticker.start("solving")
    try:
        result = _line(30.0).solve_result(seed=0, max_candidates=5, lazy_candidates=50)
        line = ticker._line(7.0)
    finally:
        ticker.stop()
    s = result.stats
    assert s.candidates == 5 and s.refuted == 5
    assert f"{s.candidates} candidates ({s.refuted} refuted, {s.abandoned} abandoned)" in line
    length = re.search(r"length (\d+)", line)
    assert length is not None and 1 <= int(length.group(1)) <= 40  # the last candidate's steps
    # the counters' logger is restored: nothing else saw its records
    progress = logging.getLogger("idstlpy.progress")
    assert progress.propagate and not progress.handlers


def test_the_line_shows_the_samplers_iterations_on_the_current_candidate():
    ticker = Ticker(io.StringIO(), enabled=True)
    ticker.start("solving")
    try:
        light_dark(60, 5).solve_result(seed=3, max_candidates=8, sampler_iterations=300)
        counters = dict(ticker._counters.counters)
    finally:
        ticker.stop()
    assert counters["candidates"] == 8
    assert "sampler_iterations" in counters and "nodes" in counters
