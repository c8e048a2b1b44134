"""The tracking gains a solve plans with: fitted to the problem, chosen by the predicted execution.

The executor tracks a plan with a finite-horizon LQR (:mod:`idstlpy.tracking`). The paper's
weights (``Q = I``, ``R = 0.05 I``: :data:`~idstlpy.tracking.DEFAULT_LQR`) ignore the problem's
units: on a DC motor turned to 1 rad within +-0.05 rad with +-2 V they track so loosely that no
plan met the execution target. By default (``SolverOptions.tracking="fitted"``) the weights are
read off the problem (Bryson's rule, :func:`~idstlpy.tracking.fitted_weights`: ``Q_ii`` from the
tightest region the formula puts on state coordinate ``i``, ``R_jj`` from the control domain's
half-width) and the search predicts each verified plan with them; a plan below the execution
target is predicted again with firmer tracking (:data:`~idstlpy.tracking.FITTED_SCALES`) and with
the paper's weights, in that order, and keeps the first gain set that meets the target (else the
one that comes closest). The returned plan carries its gains (``plan.tracking``), which the
executors use for modes without their own ``lqr_gains``. Modes with their own gains keep them;
``tracking="paper"`` plans with the paper's weights only (the behaviour before).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..sets import Polytope
from ..tracking import FITTED_SCALES, TrackingGains, fitted_weights, make_tracking

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["tracking_candidates"]


def _regions(problem: Problem) -> list[Polytope]:
    """The regions ``{x : h'x + c <= 0 for each face}`` of the formula's propositions."""
    out = []
    for ap in problem.stl_formula.atomic_propositions():
        if ap.predicates:
            out.append(
                Polytope(np.array([p.h for p in ap.predicates]), np.array([p.c for p in ap.predicates]))
            )
    return out


def tracking_candidates(problem: Problem, tracking: str) -> tuple[TrackingGains, ...]:
    """The gain sets a solve may plan with, the default first (empty: every mode has its own).

    Parameters
    ----------
    problem : Problem
    tracking : {"fitted", "paper"}
        ``SolverOptions.tracking``.

    Returns
    -------
    tuple of TrackingGains
        ``"fitted"``: the fitted weights, then :data:`~idstlpy.tracking.FITTED_SCALES` firmer
        ones, then the paper's (just the paper's when the problem has no scales to read);
        ``"paper"``: the paper's only.
    """
    system = problem.switched_system
    if all(getattr(mode, "lqr_gains", None) is not None for mode in system.system_modes):
        return ()
    paper = make_tracking(system, "paper", None)
    if tracking == "paper":
        return (paper,)
    fitted = fitted_weights(system, _regions(problem), problem.control_domain)
    if fitted is None:
        return (paper,)
    out = []
    for scale in FITTED_SCALES:
        name = "fitted" if scale == 1.0 else f"fitted x{scale:g}"
        weights = {**fitted, "Q": scale * fitted["Q"], "Q_final": scale * fitted["Q_final"]}
        out.append(make_tracking(system, name, weights))
    return (*out, paper)
