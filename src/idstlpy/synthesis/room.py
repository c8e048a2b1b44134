"""Giving a plan the execution room it needs (:mod:`.room_measure`), keeping its modes.

:func:`room_lp` is one step of sequential convex programming toward the room (the plan LP's rows
with the covariances linearised around the current plan, inside a trust region): the largest
common fraction ``t <= 1`` of the needed room, then each face's own fraction (or, for the
objectives' refiner, the least effort at that fraction). :func:`give_room` is the trust-region
repair loop (:mod:`.repair`) with the room as its score: the LP teacher's, the sampler's and the
decoupled planner's plans get their room there, and the objectives' refiner keeps it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .plan import DiscretePlan, trajectory_plan
from .plan_lp import PlanLPContext, PlanRows, Scaling, build_plan_rows, covariance_jacobian, plan_requirements
from .plan_solve import MarginModel, TrustRegion, margin_model
from .repair import repair
from .results import SolveStats

if TYPE_CHECKING:
    from ..formulas import STLFormula
    from ..problem import Problem
from .room_measure import (
    BELIEF_FAILURE,
    ROOM_FLOOR,
    STATE_FAILURE,
    Z_MAX,
    Z_MIN,
    Room,
    execution_room,
)

__all__ = [
    "BELIEF_FAILURE",
    "INPUT_LEVELS",
    "InputLevel",
    "ROOM_FLOOR",
    "STATE_FAILURE",
    "Z_MAX",
    "Z_MIN",
    "Room",
    "RoomState",
    "execution_room",
    "give_room",
    "note_room",
    "room_lp",
    "room_state",
]

logger = logging.getLogger(__name__)

INPUT_LEVELS = (1.0, 0.5, 0.0)
"""Fractions of the tracking correction's room the inputs keep, tried in turn (an LP that cannot
keep the inputs off their bounds still gives the required faces their room)."""


class InputLevel:
    """Where the next :func:`room_lp` starts among :data:`INPUT_LEVELS`: the level the last one
    kept (a search scores many plans of one candidate, most at the same level).

    The room LP keeps the first level, in :data:`INPUT_LEVELS`' order, whose LP has an optimum.
    A larger level only backs the control rows off further (the tracking correction's need is
    not negative), so an LP infeasible at one level is infeasible at every larger one: starting
    from the last level kept and moving up while the LPs stay feasible, or down while they do
    not, keeps the same level with fewer LPs (two instead of three when the inputs keep none of
    their room, sensor-switching candidates' usual case).

    Attributes
    ----------
    index : int
        Index in :data:`INPUT_LEVELS` of the level the next room LP tries first.
    """

    def __init__(self) -> None:
        self.index = 0


def _first_level(
    lp: _RoomLP, t_max: float, time_limit: float, start: InputLevel | None
) -> tuple[float, tuple[np.ndarray, float] | None]:
    """The first level of :data:`INPUT_LEVELS` whose common-fraction LP has an optimum, and that
    optimum (``(0.0, None)`` when none has); from ``start`` (:class:`InputLevel`) when given."""
    levels = INPUT_LEVELS
    solved: dict[int, tuple[np.ndarray, float] | None] = {}

    def at(i: int) -> tuple[np.ndarray, float] | None:
        if i not in solved:
            solved[i] = lp.solve(levels[i], None, 0.0, t_max, time_limit)
        return solved[i]

    i = 0 if start is None else min(max(start.index, 0), len(levels) - 1)
    if at(i) is None:
        while i + 1 < len(levels) and at(i + 1) is None:
            i += 1
        i += 1
        if i >= len(levels):
            return 0.0, None
    else:
        while i > 0 and at(i - 1) is not None:
            i -= 1
    if start is not None:
        start.index = i
    return levels[i], solved[i]


def _row_room(rows: PlanRows, room: Room, abstraction: Abstraction) -> np.ndarray:
    """The needed room of every face row of ``rows`` (raw units), in row order.

    The plan LP drops the faces that do not read the mean (their room is zero); rows of one
    requirement are in face order.
    """
    out = np.zeros(rows.face_H.shape[0])
    owner = np.asarray(rows.face_owner, dtype=np.int64)
    dx = rows.scaling.dx
    # each requirement's rows, ascending (one stable sort instead of a scan per requirement)
    order = np.argsort(owner, kind="stable")
    ends = np.cumsum(np.bincount(owner, minlength=len(room.requirements)))
    for r, (_, i) in enumerate(room.requirements):
        idx = order[(ends[r - 1] if r else 0) : ends[r]]
        if not idx.size:
            continue
        need = room.need[r]
        if idx.size == need.size:
            out[idx] = need
            continue
        live = np.linalg.norm(abstraction.atoms[i].cone.H * dx[None, :], axis=1) > 0
        out[idx] = need[live] if int(live.sum()) == idx.size else float(np.max(need, initial=0.0))
    return out


def room_lp(
    context: PlanLPContext,
    plan: DiscretePlan,
    traj: ProbabilisticTSTrajectory,
    room: Room,
    trust: float,
    *,
    effort_weights: np.ndarray | None = None,
    t_max: float = 1.0,
    time_limit: float = 1e9,
    linearise: bool = True,
    polish: bool = True,
    level: InputLevel | None = None,
    rows: PlanRows | None = None,
    smooth: bool = False,
) -> tuple[np.ndarray, float] | None:
    """One SCP step toward the room: controls keeping the largest common fraction of it.

    The plan LP's rows (of ``context``) for ``plan`` around ``traj`` (its covariances frozen,
    their dependence on the means linearised, every mean within ``trust`` of ``traj``'s), every
    control face ``f`` at step ``k`` backed off by ``level * input_need_kf`` (the first feasible
    level of :data:`INPUT_LEVELS`), every required face by ``t * need_kf``: maximises the common
    fraction ``t`` in ``[0, t_max]``, then either each face's own fraction ``t_kf`` in
    ``[t, t_max]`` (their sum: a face that cannot get its room does not hold the others back)
    or, with ``effort_weights``, minimises the weighted input effort at ``t``.

    Parameters
    ----------
    context : PlanLPContext
        The solve's plan LP context (its back-end solves the LPs).
    plan : DiscretePlan
        The requirements ``traj`` meets (``room``'s), ``L`` steps.
    traj : ProbabilisticTSTrajectory
        The current plan (its MLO roll-out).
    room : Room
        ``traj``'s room (:func:`execution_room`).
    trust : float
        Largest move of every mean (infinity norm, state units); infinite: none.
    effort_weights : ndarray, shape (m,), optional
        Minimise the weighted effort at the fraction reached (the objectives' refiner).
    t_max : float
        Largest fraction of the room asked for.
    time_limit : float
        Seconds for each LP.
    linearise : bool
        With the covariances' first-order dependence on the means (False: exact without
        state-dependent noise, and a third of the cost).
    polish : bool
        After the common fraction, each face's own (or the effort); False: stop after the
        common fraction (what the mode search scores).
    level : InputLevel, optional
        Where the search for the first feasible input level starts, updated to the level kept
        (the same level, with fewer LPs, when consecutive LPs keep the same one).
    rows : PlanRows, optional
        The plan LP's rows of ``plan`` (:attr:`~.plan_solve.LPOutcome.rows`): used instead of
        building them when they are the same (not linearised, the same requirements and
        covariances as ``traj``'s).
    smooth : bool
        With ``effort_weights``: minimise the weighted total variation of the inputs
        (``sum |u_{k+1} - u_k|``) instead of their effort.

    Returns
    -------
    (controls, t) or None
        Controls, shape (L - 1, m), and the common fraction reached; None when no LP has an
        optimum (the trust region keeps no plan meeting the requirements).
    """
    lp = _RoomLP.around(context, plan, traj, room, trust, linearise, rows)
    if lp is None:
        return None
    kept, first = _first_level(lp, t_max, time_limit, level)
    if first is None:
        return None
    z, t = first
    t_keep = max(0.0, t * (1 - 1e-6))
    second = None
    if not polish:
        pass
    elif effort_weights is not None:
        effort = np.asarray(effort_weights, dtype=float)
        second = lp.solve(kept, effort, t_keep, max(t, 0.0), time_limit, differences=smooth)
    elif lp.rows.face_H.shape[0] > 0 and t < t_max - 1e-9:  # at t_max every face has its room
        second = lp.solve(kept, None, t_keep, max(t_max, t_keep), time_limit, per_face=True)
    if second is not None:
        z = second[0]
    _, controls = lp.rows.unscale(z, context.mean0)
    return controls, t


@dataclass(frozen=True)
class _RoomLP:
    """The room LP's pieces around one plan (:func:`room_lp`): the linearised plan rows, each
    face row's needed room, each control row's back-off and the trust region."""

    context: PlanLPContext
    rows: PlanRows
    face_coef: np.ndarray
    u_shift: np.ndarray
    region: TrustRegion
    # the LPs built so far, by (t_lo, t_hi, per_face): the input levels' LPs differ only in the
    # control rows' right-hand side (built once: the model's set-up costs about its solve)
    built: dict[tuple[float, float, bool], MarginModel] = field(default_factory=dict, compare=False)

    @classmethod
    def around(
        cls,
        context: PlanLPContext,
        plan: DiscretePlan,
        traj: ProbabilisticTSTrajectory,
        room: Room,
        trust: float,
        linearise: bool = True,
        built: PlanRows | None = None,
    ) -> _RoomLP | None:
        """The pieces for ``plan`` around ``traj``; None when no LP can be built (``linearise``:
        with the covariances' first-order dependence on the means; ``built``: the plan LP's
        rows of ``plan``, read when they are the ones this LP needs)."""
        K = plan.num_transitions
        if K <= 0:
            return None
        actions = np.asarray(plan.modes[1 : K + 1], dtype=int)
        scaling, abstraction = context.scaling, context.abstraction
        means, covs = traj.get_mean()[: K + 1], traj.get_cov()[: K + 1]
        reqs = plan_requirements(plan, abstraction)
        if reqs != room.requirements:
            return None
        lin = None
        if linearise:
            lin = (covariance_jacobian(context.system.system_modes, actions, means, covs, scaling.dx), means)
        if built is not None and lin is None and built.requirements == reqs and _same(built.covs, covs):
            rows = built  # the same inputs as the build below: the same rows, entry for entry
        else:
            rows = build_plan_rows(context, reqs, actions, covs, linearisation=lin)
        if rows.impossible:
            return None
        need = _row_room(rows, room, abstraction) + 1e-9 * float(np.min(scaling.dx))
        # control rows: normalised per face, zero rows dropped (as plan_lp builds them), step-major
        unorm = np.linalg.norm(context.control_domain.H * scaling.du[None, :], axis=1)
        keep = unorm > 0
        u_shift = (room.input_need[:K][:, keep] / unorm[keep][None, :]).ravel()
        if u_shift.shape[0] != rows.A_U.shape[0]:
            u_shift = np.zeros(rows.A_U.shape[0])
        return cls(context, rows, need * rows.face_unit, u_shift, TrustRegion(means, trust))

    def solve(
        self,
        level: float,
        effort: np.ndarray | None,
        t_lo: float,
        t_hi: float,
        time_limit: float,
        per_face: bool = False,
        differences: bool = False,
    ) -> tuple[np.ndarray, float] | None:
        """One LP (:func:`~.plan_solve.margin_phase`): the inputs backed off by ``level`` of
        their need, the fraction(s) of the room in ``[t_lo, t_hi]`` maximised (``effort``: the
        weighted effort, or with ``differences`` the inputs' total variation, minimised instead)."""
        rows = self.rows
        b_U = rows.b_U - level * self.u_shift
        if effort is not None:
            model = self._model(t_lo, t_hi, per_face, effort, b_U, differences)
        else:
            key = (t_lo, t_hi, per_face)
            if key in self.built:
                model = self.built[key].with_b_U(b_U)
            else:
                model = self.built[key] = self._model(t_lo, t_hi, per_face, None, b_U)
        return model.solve(self.context.backend, time_limit)

    def _model(
        self,
        t_lo: float,
        t_hi: float,
        per_face: bool,
        effort: np.ndarray | None,
        b_U: np.ndarray,
        differences: bool = False,
    ) -> MarginModel:
        return margin_model(
            self.rows,
            t_lo=t_lo,
            t_hi=t_hi,
            coef=self.face_coef,
            per_face=per_face,
            effort=effort,
            region=self.region,
            b_U=b_U,
            differences=differences,
        )


def _same(a: np.ndarray | None, b: np.ndarray) -> bool:
    """Whether ``a`` holds ``b`` (and no more steps)."""
    return a is not None and a.shape == b.shape and bool(np.array_equal(a, b))


@dataclass(frozen=True)
class RoomState:
    """A plan the monitor accepts, the requirements it meets (its earliest witness) and its room."""

    traj: ProbabilisticTSTrajectory
    plan: DiscretePlan
    room: Room


def room_state(
    context: PlanLPContext, formula: STLFormula, traj: ProbabilisticTSTrajectory
) -> RoomState | None:
    """``traj``'s witness (:func:`~.plan.trajectory_plan`) and its execution room, or None."""
    plan = trajectory_plan(formula, context.abstraction, traj)
    if plan is None:
        return None
    room = execution_room(context.system, context.control_domain, context.abstraction, plan, traj)
    return None if room is None else RoomState(traj, plan, room)


def give_room(
    problem: Problem,
    abstraction: Abstraction,
    scaling: Scaling,
    traj: ProbabilisticTSTrajectory,
    rounds: int,
    stats: SolveStats,
    deadline: float | None = None,
) -> ProbabilisticTSTrajectory:
    """Give a plan the room its execution needs, keeping its modes (sequential convex programming).

    The trust-region repair (:func:`.repair.repair`) with the room as its score: each round
    solves one step toward the room of the requirements the plan meets (:func:`room_lp`, means
    within ``trust``); the re-rolled plan is kept only if the monitor still accepts it and its
    room improved (:meth:`Room.better_than`); ``trust`` halves after a round that did not help.
    It stops when the room is complete (:attr:`Room.complete`), or after a failed round once
    every required face has its room. Where the plan LP is exact (:func:`~.plan_lp.lp_exact`)
    the covariances do not depend on the means and the rounds have no trust region.

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    scaling : Scaling
    traj : ProbabilisticTSTrajectory
        A plan (its MLO roll-out) the monitor accepts.
    rounds : int
        Work budget: LP rounds.
    stats : SolveStats
        ``lp_calls`` is counted here, the room kept in ``execution_room`` (:func:`note_room`).
    deadline : float, optional
        ``time.perf_counter()`` value (the solve's time limit) after which no round starts; each
        round's LP gets the time left. The plan so far is returned: the room is anytime.

    Returns
    -------
    ProbabilisticTSTrajectory
        A plan the monitor accepts with at least ``traj``'s room (``traj`` itself when the monitor
        rejects it: nothing to give room to).
    """
    formula = problem.stl_formula
    if robustness(traj, formula) < 0 or rounds <= 0:
        return traj
    context = PlanLPContext.of(problem, abstraction, scaling)
    start = room_state(context, formula, traj)
    if start is None:
        return traj
    end = repair(_RoomSteps(context, problem, stats), start, rounds, deadline=deadline)
    note_room(stats, end.room)
    return end.traj


class _RoomSteps:
    """:func:`give_room`'s parts of the repair loop (:class:`.repair.RepairSteps`)."""

    name = "room"

    def __init__(self, context: PlanLPContext, problem: Problem, stats: SolveStats) -> None:
        self.context = context
        self.formula = problem.stl_formula
        self.init = problem.initial_state
        self.stats = stats
        # Exact: the LP is exact for the frozen requirements and needs no trust region (the LP
        # path's plans), and a step that did not help is not helped by a smaller one.
        self.exact = context.exact

    def done(self, state: RoomState) -> bool:
        return state.room.complete

    def first_trust(self, state: RoomState) -> float:
        if self.exact:
            return np.inf
        return max(2.0 * state.room.largest_need, 1e-3 * float(np.max(self.context.scaling.dx)))

    def propose(
        self, state: RoomState, trust: float, left: float
    ) -> tuple[ProbabilisticTSTrajectory, float] | None:
        self.stats.lp_calls += 1
        # Exact: the covariances do not depend on the means, their linearisation is zero (and
        # costs a third of the LP's set-up).
        out = room_lp(
            self.context, state.plan, state.traj, state.room, trust, time_limit=left, linearise=not self.exact
        )
        if out is None:
            return None
        # The LP moves the witness's steps; the plan keeps its length (its callers pair the
        # controls with the candidate's modes), later steps keep their inputs.
        controls = np.array(state.traj.get_control(), dtype=float, copy=True)
        controls[: state.plan.length - 1] = out[0]
        moved = rollout(self.context.system, self.init, state.traj.get_action(), controls)
        return moved, out[1]

    def accept(
        self, state: RoomState, proposal: tuple[ProbabilisticTSTrajectory, float], trust: float
    ) -> RoomState | None:
        moved, fraction = proposal
        if robustness(moved, self.formula) < 0:
            return None
        found = room_state(self.context, self.formula, moved)
        if found is None or not found.room.better_than(state.room):
            return None
        room, new = state.room, found.room
        logger.debug(
            "room: %.3g -> %.3g, mean %.3g -> %.3g, inputs %.3g -> %.3g (trust %.3g, LP fraction %.3g)",
            room.score,
            new.score,
            room.coverage,
            new.coverage,
            room.input_score,
            new.input_score,
            trust,
            fraction,
        )
        return found

    def stuck(self, state: RoomState, failures: int) -> bool:
        # the faces have their room (only the inputs' is missing), or no smaller step helps
        return state.room.score >= 1.0 or self.exact


def note_room(stats: SolveStats, room: Room) -> None:
    """Record the room the returned plan keeps (``stats.execution_room``); warn when short of it."""
    stats.execution_room = float(room.score)
    level = logging.INFO if room.score >= 1.0 else logging.WARNING
    logger.log(
        level,
        "room: the plan keeps %.3g of the room its execution needs (z %.2f belief, %.2f state)%s",
        room.score,
        room.z_belief,
        room.z_state,
        "" if room.score >= 1.0 else ": expect it to hold in fewer than 90% (belief) / 95% (state) of runs",
    )
