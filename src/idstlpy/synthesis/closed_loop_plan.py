"""What ``guarantee="closed_loop"`` checks of a plan, and the plan LP that leaves the tracking
correction its room (:func:`closed_loop_check`, :func:`closed_loop_lp`), with the execution margin
every noisy plan keeps (:func:`execution_margin`). Used by the LP teacher (:mod:`.teacher`) and
the closed-loop repair (:mod:`.certify`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..closed_loop import (
    TRACKABLE_Z,
    predicted_state,
    projection_left_out,
    trackable,
    tracking_backoff,
    tracking_spread,
)
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .plan import DiscretePlan
from .plan_solve import LPOutcome

if TYPE_CHECKING:
    from ..belief import GaussianBelief
    from ..dynamical_system import SwitchedSystem
    from ..formulas import STLFormula
    from ..sets import Polytope

__all__ = ["BACKOFF_LEVELS", "closed_loop_check", "closed_loop_lp", "execution_margin"]

logger = logging.getLogger(__name__)


def _noisy(system: SwitchedSystem, init: GaussianBelief) -> bool:
    """Whether a plan will meet noise: an uncertain start, process noise or a sensor."""
    return bool(np.any(init.cov != 0)) or any(
        np.any(mode.process_cov != 0) or mode.p > 0 for mode in system.system_modes
    )


def execution_margin(
    system: SwitchedSystem, init: GaussianBelief, abstraction: Abstraction, plan: DiscretePlan
) -> float:
    """Room to leave inside required regions when the plan will meet noise (0 when it will not).

    Half the Chebyshev radius of the smallest bounded required region (one unit of the largest
    state scale when every required region is unbounded).
    """
    if not _noisy(system, init):
        return 0.0
    radii = []
    for i in np.nonzero(plan.required.any(axis=1))[0]:
        radius = abstraction.radius(int(i))
        if np.isfinite(radius):
            radii.append(radius)
    if radii:
        return 0.5 * min(radii)
    return 0.0


BACKOFF_LEVELS = (2.0, TRACKABLE_Z)
"""Standard deviations of the tracking correction kept free on every face of the control domain
by plans made under ``guarantee="closed_loop"``, tried in turn (``Phi(2) = 97.7%`` per face and
step first; the last level is what :func:`idstlpy.closed_loop.trackable` asks of a plan)."""


def closed_loop_check(
    system: SwitchedSystem, traj: ProbabilisticTSTrajectory, control_domain: Polytope, formula: STLFormula
) -> tuple[ProbabilisticTSTrajectory, float, bool, bool]:
    """What ``guarantee="closed_loop"`` verifies of a plan.

    Parameters
    ----------
    system : SwitchedSystem
    traj : ProbabilisticTSTrajectory
        The plan (its MLO roll-out).
    control_domain : Polytope
    formula : PrSTL formula
        What the predicted true state must satisfy.

    Returns
    -------
    predicted : ProbabilisticTSTrajectory
        The true state predicted under the executor (:func:`idstlpy.closed_loop.predicted_state`).
    margin : float
        The monitor's robustness of ``predicted``.
    ok : bool
        ``margin >= 0``.
    tracks : bool
        Whether the plan is trackable (:func:`idstlpy.closed_loop.trackable`; False, not asked,
        when the Gaussian prediction already fails): the prediction
        linearises the clipping of the correction, and is accurate where the inputs leave the
        correction room. A plan that is not is judged on the particle closure instead (samples
        pushed through the clip: a plan riding an input bound makes the clipped loop a rectifier
        whose spread the linearisation under-states); so is a plan whose input leaves a
        non-box domain with probability above 1% at some step
        (:func:`idstlpy.closed_loop.projection_left_out`). The planner tries one repair of a passing
        plan that is not trackable and keeps it if the repair does not give a trackable one.

    Notes
    -----
    The particle closure costs about ten Gaussian ones (4000 samples), so an untrackable plan is
    screened first: when its Gaussian prediction already fails, that is the verdict (``ok`` is
    False, ``predicted`` and ``margin`` the Gaussian closure's). The screen only ever rejects:
    a plan is accepted on the particle closure alone, so soundness is untouched. It may reject
    a plan the particles would pass only when the linearisation is the more pessimistic of the
    two, which a rectifier's under-stated spread makes rare and small (on the suite's MLO plans
    the particle margin was at most 6e-4 above the Gaussian one, usually below it).
    """
    predicted = predicted_state(system, traj, control_domain, closure="gaussian")
    margin = robustness(predicted, formula)
    if margin < 0:
        # The screen's verdict; trackability (a loop of its own) is not asked of a failing plan.
        return predicted, margin, False, False
    tracks = trackable(system, traj, control_domain)
    # a domain that is not a box: the Gaussian closure leaves its projection out (no closed form)
    if control_domain is not None and (not tracks or projection_left_out(system, traj, control_domain)):
        predicted = predicted_state(system, traj, control_domain, closure="particles")
        margin = robustness(predicted, formula)
    return predicted, margin, margin >= 0, tracks


def closed_loop_lp(
    system: SwitchedSystem,
    traj: ProbabilisticTSTrajectory,
    control_domain: Polytope,
    predicted: ProbabilisticTSTrajectory,
    solve: Callable[[np.ndarray | None, np.ndarray], LPOutcome],
) -> LPOutcome:
    """The next plan LP under ``guarantee="closed_loop"``, with room for the tracking correction.

    Inputs on the domain's boundary leave the tracking correction no room (the executor clips
    it and the true state drifts), so the next plan keeps ``z`` standard deviations of the
    correction free on every face at every step (:func:`idstlpy.closed_loop.tracking_backoff`),
    its covariances those of the unclipped loop. The levels of :data:`BACKOFF_LEVELS` are tried
    until one LP is feasible; last, no back-off with the ``predicted`` covariances (clipping
    included), which is also what a domain without faces gets.

    Parameters
    ----------
    system : SwitchedSystem
    traj : ProbabilisticTSTrajectory
        The current plan (its MLO roll-out), ``K`` steps.
    control_domain : Polytope
    predicted : ProbabilisticTSTrajectory
        Its predicted true state, clipping included.
    solve : callable
        ``solve(control_backoff, covs)``: the plan LP with a back-off (shape (K, F), or None)
        and frozen covariances (shape (K + 1, n, n)).

    Returns
    -------
    LPOutcome
        The first feasible LP's, else the last one's.
    """
    if not control_domain.H.shape[0] or not traj.num_of_steps:
        return solve(None, predicted.get_cov())
    covs = predicted_state(system, traj, None).get_cov()
    spread = tracking_spread(system, traj, control_domain)
    out = solve(tracking_backoff(system, traj, control_domain, BACKOFF_LEVELS[0], spread), covs)
    for z in BACKOFF_LEVELS[1:]:
        if out.feasible:
            return out
        out = solve(tracking_backoff(system, traj, control_domain, z, spread), covs)
    if out.feasible:
        return out
    logger.debug("closed-loop LP: no plan keeps the tracking correction room; none kept")
    # No trackable plan on these requirements: one that rides the faces, judged with the
    # clipping's linearisation, is better than none (the loop flags it, see closed_loop_check).
    return solve(None, predicted.get_cov())
