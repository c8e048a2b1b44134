"""The final check of a plan: everything a ``found`` promises, in one place (:func:`final_check`).

Every plan the loop returns passes it: the exact MLO belief roll-out of its modes and controls,
its inputs inside the control domain (to a tolerance in the inputs' units), and the monitor, on
the MLO belief or, under ``guarantee="closed_loop"``, on the true state predicted under the
executor. Inputs far outside the problem's scale on an unbounded control domain are allowed but
warned about.
"""

from __future__ import annotations

import logging
import warnings
from typing import TYPE_CHECKING

import numpy as np

from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .context import SolveContext, Verified
from .plan_lp import Scaling
from .teacher import closed_loop_check

if TYPE_CHECKING:
    from ..dynamical_system import SwitchedSystem
    from ..sets import Polytope

__all__ = ["DOMAIN_TOL", "FAR_INPUTS", "final_check"]

logger = logging.getLogger(__name__)


def final_check(ctx: SolveContext, traj: ProbabilisticTSTrajectory | None) -> Verified | None:
    """The final check of a plan: everything a ``found`` promises, in one place.

    1. the dynamics: the belief is re-rolled from the plan's modes and controls with the exact
       MLO belief dynamics (:func:`~idstlpy.belief.rollout`), and that roll-out is what is
       judged and returned;
    2. the control domain: every input meets every face of ``control_domain`` to
       :data:`DOMAIN_TOL` of the input's unit (:func:`_outside_domain`);
    3. the monitor: on the MLO belief, or under ``guarantee="closed_loop"`` on the true state
       predicted under the executor.

    Inputs far outside the problem's scale on an unbounded control domain are allowed but
    warned about (:func:`_warn_far_inputs`). Returns ``None`` when a promise is broken.
    """
    if traj is None:
        return None
    problem = ctx.problem
    formula = problem.stl_formula
    traj = rollout(problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control())
    why = _outside_domain(problem.control_domain, traj.get_control(), ctx.units.du)
    if why:
        logger.warning("a plan was rejected by the final check: %s", why)
        return None
    if not ctx.closed_loop:
        margin = robustness(traj, formula)
        checked = Verified(traj, margin, None) if margin >= 0 else None
    else:
        predicted, margin, ok, _ = closed_loop_check(
            problem.switched_system, traj, problem.control_domain, formula
        )
        checked = Verified(traj, margin, predicted) if ok else None
    if checked is not None:
        _warn_far_inputs(ctx, traj.get_control())
    return checked


DOMAIN_TOL = 1e-6
"""How far (in units of the inputs, :class:`~.plan_lp.Scaling`'s ``du``, along each face's
normal) an input may lie outside the control domain and still count as inside it: the LPs'
tolerances are 1e-7 on the same scaled rows."""

FAR_INPUTS = 1e3
"""On an unbounded control domain, inputs beyond this many of the problem's input scale are
warned about (:func:`_warn_far_inputs`)."""


def _outside_domain(domain: Polytope, controls: np.ndarray, du: np.ndarray) -> str:
    """Why ``controls`` (shape (N, m)) break ``domain``, or ``""`` when every input meets it.

    Each face ``h'u + c <= 0`` is measured in the inputs' units: ``(h'u + c) / ||h * du||``
    (``du``, shape (m,): :class:`~.plan_lp.Scaling`'s input units).
    """
    if controls.shape[0] == 0 or domain.H.shape[0] == 0:
        return ""
    if not np.all(np.isfinite(controls)):
        return "the plan's inputs are not finite"
    norms = np.linalg.norm(domain.H * du[None, :], axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    excess = (controls @ domain.H.T + domain.c[None, :]) / norms[None, :]
    worst = float(np.max(excess))
    if worst <= DOMAIN_TOL:
        return ""
    k, f = np.unravel_index(int(np.argmax(excess)), excess.shape)
    return (
        f"the input at step {int(k)} ({np.array2string(controls[k], precision=6)}) breaks face "
        f"{int(f)} of the control domain by {worst:.3g} of its unit (tolerance {DOMAIN_TOL:g})"
    )


def _warn_far_inputs(ctx: SolveContext, controls: np.ndarray) -> None:
    """Warn when a plan on an unbounded control domain uses inputs far outside the problem's scale.

    Inputs beyond :data:`FAR_INPUTS` times the input scale (:func:`_input_scale`) are legal
    but rarely meant (a domain bounded on one side only): a ``UserWarning`` and a logged warning.
    """
    scale = _input_scale(ctx.problem.switched_system, ctx.problem.control_domain, ctx.units)
    if controls.shape[0] == 0 or scale is None:
        return
    ratio = np.max(np.abs(controls), axis=0) / scale
    if not np.any(ratio > FAR_INPUTS):
        return
    j = int(np.argmax(ratio))
    msg = (
        f"the plan uses input u[{j}] = {float(np.max(np.abs(controls[:, j]))):.6g}, "
        f"{float(ratio[j]):.3g} times the problem's input scale ({float(scale[j]):.3g}), "
        "on an unbounded control_domain: bound the control domain if such inputs are not meant"
    )
    logger.warning(msg)
    warnings.warn(msg, UserWarning, stacklevel=2)


def _input_scale(system: SwitchedSystem, domain: Polytope, units: Scaling) -> np.ndarray | None:
    """Per input, the scale :func:`_warn_far_inputs` compares a plan's inputs with, shape (m,);
    ``None`` when the control domain is bounded (the domain itself then bounds the inputs).

    The larger of the input's unit and, where some mode's ``B`` moves the state with it, the
    input that moves a state coordinate by one of its units in one step (``dx_i / |B_ij|``).
    """
    low, high = domain.bounding_box()
    if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):
        return None
    scale = np.array(units.du, dtype=float)
    for mode in system.system_modes:
        B = np.abs(mode.B)
        with np.errstate(divide="ignore"):
            reach = np.where(B > 0, units.dx[:, None] / np.where(B > 0, B, 1.0), np.inf)
        move = np.min(reach, axis=0)
        scale = np.maximum(scale, np.where(np.isfinite(move), move, 0.0))
    return scale
