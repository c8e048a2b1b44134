"""The mode search: which mode to use at each step of a discrete plan (issues 23 and 24).

A candidate from the proposer fixes its requirements (which regions hold at which steps) and a
mode sequence. When several modes serve those requirements, the proposer's sequence is only a
guess, and walking sequences one clause at a time costs ``2^K`` candidates. The search instead
changes the modes of one candidate, guided by a score that sees what each choice does:

- **the paper's reading** (:class:`MLOScore`): the elastic plan LP's total violation, which sees
  what each mode does to the means and to the covariance schedule; a sequence whose LP is
  feasible ends the search;
- **the execution's reading** (:class:`RoomScore`, ``guarantee="execution"``): among sequences
  whose plan LP is feasible, the largest common fraction of the execution room
  (:mod:`.room`) the plan can keep with them. Under the MLO reading a measurement taken in place
  collapses the covariance without moving the robot, so a plan may "look on the last step" and
  meet the formula on paper, while executed the look's innovation moves the belief's mean and
  nothing is left to correct it. The room is the closed loop's predicted spread of the belief's
  mean and of the true state; a sequence whose predicted failures are within the execution
  target ends the search.

The search is local: one step's mode is changed at a time (the steps just before the step that
needs it first: a look before the step whose requirement it serves), or a switch is moved by one
step, and the first change that improves the score is kept. It starts from the best of the
proposed modes and each mode held throughout (most plans are one mode with a few switches);
from a local minimum it restarts once from the last search's best modes fitted to this length
(the next candidate is often one step longer). It stops at a sequence that ends the search or
after :data:`MODE_SEARCH_LPS` scored sequences per transition (a work budget, so the same problem
gives the same plan). The search proves nothing: only a refutation of the proposed modes is a
proof, and the caller keeps it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..belief import rollout
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .interfaces import Budget
from .plan import DiscretePlan
from .plan_lp import PlanLPContext
from .room import InputLevel, room_lp
from .room_measure import execution_room, mlo_means, plan_have

if TYPE_CHECKING:
    from ..belief import GaussianBelief
    from ..dynamical_system import SwitchedSystem
    from ..problem import Problem
    from .plan_solve import LPOutcome
    from .room_measure import Room

__all__ = [
    "MODE_SEARCH_LPS",
    "MLOScore",
    "ModeSearch",
    "RoomScore",
    "Score",
    "Trial",
    "allowed_modes",
    "lp_trial",
]

logger = logging.getLogger(__name__)

MODE_SEARCH_LPS = 6
"""Scored sequences per transition the mode search may spend on a candidate (a work budget)."""

ROOM_WINDOW = 8
"""Steps before the step short of its room (and one after) at which the search changes the modes
of a sequence the plan LP meets (a look serves the steps just after it)."""

ROOM_DONE = 1.0 - 1e-6
"""Common fraction of the execution room a plan keeps beyond which :class:`RoomScore` does not
ask the room LP for more (every required face keeps all of it, up to the LP's tolerance)."""

Key = tuple[int, float]
"""A sequence's score, compared lexicographically (larger is better): the class (``-1`` the LP
gave no answer, ``0`` the plan LP is infeasible, ``1`` it is feasible), then the value within
the class (minus the elastic violation; the room's common fraction)."""

_UNSCORED: Key = (-1, 0.0)


@dataclass(frozen=True)
class Trial:
    """One scored mode sequence.

    Attributes
    ----------
    modes : ndarray, shape (L,)
        The modes arriving at each step (``modes[0]`` the initial one).
    key : Key
        Its score.
    done : bool
        Whether it ends the search (its score is as good as a score can be).
    focus : int
        The step a better sequence should change the modes before (the earliest violated
        requirement; the step of the face with the least room).
    """

    modes: np.ndarray
    key: Key
    done: bool
    focus: int


class Score(Protocol):
    """Scores a mode sequence for a candidate's requirements."""

    def __call__(self, plan: DiscretePlan) -> Trial:
        """The trial of ``plan`` (its requirements with the modes to score)."""
        ...


LPSolve = Callable[[DiscretePlan], "LPOutcome"]
"""``solve(plan)``: the elastic plan LP of ``plan`` (``refute_only``), an
:class:`~.teacher.LPOutcome`."""


def _improves(a: Key, b: Key) -> bool:
    """Whether ``a`` is better than ``b`` by more than the LP's relative noise."""
    if a[0] != b[0]:
        return a[0] > b[0]
    return a[1] > b[1] + 1e-6 * abs(b[1])


def lp_trial(plan: DiscretePlan, out: LPOutcome) -> Trial:
    """A trial scored by the plan LP's outcome alone."""
    K = plan.num_transitions
    if out.status == "feasible":
        return Trial(plan.modes, (1, 0.0), True, K)
    if out.status == "infeasible" and np.isfinite(out.excess):
        focus = min((k for k, _ in out.conflict), default=K)
        return Trial(plan.modes, (0, -float(out.excess)), False, focus)
    return Trial(plan.modes, _UNSCORED, False, K)


class MLOScore:
    """The paper's reading: the elastic plan LP's total violation; feasible ends the search.

    Parameters
    ----------
    solve : callable
        The elastic plan LP of a plan (see :data:`LPSolve`).
    """

    def __init__(self, solve: LPSolve) -> None:
        self.solve = solve

    def __call__(self, plan: DiscretePlan) -> Trial:
        return lp_trial(plan, self.solve(plan))


class RoomScore:
    """The execution's reading: a feasible plan LP, then the execution the modes let it have.

    A sequence whose plan LP is infeasible is scored as by :class:`MLOScore`. One whose plan LP
    is feasible is rolled out and its closed loop predicted (:func:`~.room.execution_room`); the
    controls that keep the largest common fraction of the needed room with these modes are
    found (:func:`~.room.room_lp`, no trust region: the LP is exact where the search runs), and
    the plan they make is scored by the loop's predicted failure probabilities
    (:meth:`~.room.Room.failure`, per reading): ``(1, v)`` with ``v`` the least of the two
    allowances left (``1 - target - failure``); ``v >= 0`` ends the search. The loop still
    predicts the returned plan's execution on its own (particles); this is the search's guide.

    Parameters
    ----------
    problem : Problem
    context : PlanLPContext
        The solve's plan LP context (abstraction, units, back-end).
    solve : callable
        The elastic plan LP of a plan (see :data:`LPSolve`).
    time_left : callable
        Seconds left for one LP (the solve's budget).
    target : (belief, state)
        The execution target's success rates.
    """

    def __init__(
        self,
        problem: Problem,
        context: PlanLPContext,
        solve: LPSolve,
        time_left: Callable[[], float],
        target: tuple[float, float],
    ) -> None:
        self.problem = problem
        self.context = context
        self.abs = context.abstraction
        self.solve = solve
        self.time_left = time_left
        self.allowance = (1.0 - float(target[0]), 1.0 - float(target[1]))
        self.level = InputLevel()  # the sequences of one candidate mostly keep the same input level

    def __call__(self, plan: DiscretePlan) -> Trial:
        out = self.solve(plan)
        if out.status != "feasible" or out.controls is None:
            return lp_trial(plan, out)
        problem = self.problem
        system, init, domain = problem.switched_system, problem.initial_state, problem.control_domain
        K = plan.num_transitions
        actions = np.asarray(plan.modes[1 : K + 1], dtype=int)
        traj = _rolled(system, init, actions, out.controls, out)
        room = execution_room(system, domain, self.abs, plan, traj)
        if room is None:  # the predicted loop diverges: the least of the feasible sequences
            return Trial(plan.modes, (1, -2.0), False, K)
        have = room.have
        if room.score < ROOM_DONE:
            best = room_lp(
                self.context, plan, traj, room, np.inf,
                time_limit=max(self.time_left(), 1e-3), linearise=False, polish=False,
                level=self.level, rows=out.rows,
            )  # fmt: skip
            if best is not None:
                # the same modes keep the covariances: only the means are rolled out again
                controls = np.asarray(best[0], dtype=float).reshape(K, system.m)
                have = plan_have(self.abs, room, mlo_means(system, init.mean, actions, controls))
        belief, state = room.failure(have)
        value = min(self.allowance[0] - belief, self.allowance[1] - state)
        return Trial(plan.modes, (1, value), value >= 0.0, _tightest_step(room, have, K))


def _rolled(
    system: SwitchedSystem, init: GaussianBelief, actions: np.ndarray, controls: np.ndarray, out: LPOutcome
) -> ProbabilisticTSTrajectory:
    """The MLO roll-out of ``controls``, a feasible plan LP's (``out``; :func:`~idstlpy.belief.rollout`).

    Where the schedule is exact (no state-dependent noise), the plan LP's covariances are the
    roll-out's, to the bit (:func:`~.covariances.covariance_schedule` makes the same updates
    with the same noise): only the means are rolled out (the covariances' Kalman updates are
    most of a roll-out's cost)."""
    K = actions.shape[0]
    covs = out.covs
    if out.exact and covs is not None and covs.shape == (K + 1, system.n, system.n):
        u = np.asarray(controls, dtype=float).reshape(K, system.m)
        return ProbabilisticTSTrajectory(mlo_means(system, init.mean, actions, u), covs, actions, u)
    return rollout(system, init, actions, controls)


def _tightest_step(room: Room, have: list[np.ndarray], K: int) -> int:
    """The step of the required face that keeps the smallest fraction of its room."""
    worst, step = np.inf, K
    for (k, _), kept, need in zip(room.requirements, have, room.need, strict=True):
        if not need.size:
            continue
        ratio = float(np.min(kept / np.maximum(need, 1e-12)))
        if ratio < worst:
            worst, step = ratio, int(k)
    return step


def allowed_modes(plan: DiscretePlan, abstraction: Abstraction, num_modes: int) -> list[list[int]]:
    """Per step ``k`` (``0..K``), the modes a plan may arrive with (its required mode atoms')."""
    out: list[list[int]] = [[]]
    for k in range(1, plan.length):
        allowed = set(range(num_modes))
        for i in np.nonzero(plan.required[:, k])[0]:
            modes = abstraction.mode_sets[int(i)]
            if modes is not None:
                allowed &= {int(q) for q in modes}
        out.append(sorted(allowed))
    return out


class ModeSearch:
    """Local search over a candidate's mode sequence (module notes), with a memory.

    Parameters
    ----------
    num_modes : int
    abstraction : Abstraction

    Attributes
    ----------
    best_modes : ndarray or None
        The last search's best sequence (the next search restarts from it).
    """

    def __init__(self, num_modes: int, abstraction: Abstraction) -> None:
        self.num_modes = num_modes
        self.abs = abstraction
        self.best_modes: np.ndarray | None = None
        self.best_met = False  # whether the plan LP met the best modes (a warm start's condition)

    def run(
        self,
        plan: DiscretePlan,
        score: Score,
        first: Trial | None = None,
        warm: bool = False,
        budget: Budget | None = None,
    ) -> Trial | None:
        """The best trial for ``plan``'s requirements (``done`` when it ends the search).

        Parameters
        ----------
        plan : DiscretePlan
            The candidate (requirements and proposed modes).
        score : Score
        first : Trial, optional
            The proposed modes' trial when already scored.
        warm : bool
            When the plan LP met the last search's best modes, take them as one more start of a
            single descent (instead of a second descent from them after the first): the room's
            search refines the last plan that holds best, one step longer.
        budget : Budget, optional
            Checked between moves (the solve's caps).

        Returns
        -------
        Trial or None
            None when the search does not apply (one transition's choice or none) or the
            proposed modes could not be scored.
        """
        K = plan.num_transitions
        allowed = allowed_modes(plan, self.abs, self.num_modes)
        if K == 0 or all(len(a) <= 1 for a in allowed[1:]):
            return None
        walk = _Walk(plan, score, allowed, MODE_SEARCH_LPS * K, budget)
        # the proposed modes' score is not counted against the search's work budget
        start = first if first is not None else score(plan)
        if start.done:
            return start
        if start.key[0] < 0:
            return None
        best = walk.starts(start, self.num_modes)
        previous = self.best_modes if self.best_modes is not None and self.best_modes.shape[0] > 1 else None
        if warm and previous is not None and self.best_met and not best.done:
            # The last search's best modes are one more start (the next candidate is often one
            # step longer): a single descent from the best start instead of two.
            fitted = walk.fit(previous)
            if fitted is not None:
                trial = walk.score(fitted)
                if trial.done or (trial.key[0] >= 0 and trial.key > best.key):
                    best = trial
            previous = None
        if not best.done:
            best = walk.descend(best)
        if not best.done and previous is not None:
            again = walk.restart(previous, best)
            if again is not None and (again.done or again.key > best.key):
                best = again
        logger.debug(
            "mode search (%d steps): %s after %d scored sequences (score %s)",
            K,
            "done" if best.done else "stopped",
            walk.count,
            best.key,
        )
        self.best_modes = best.modes.copy()
        self.best_met = best.key[0] == 1
        return best


class _Walk:
    """One search's moves and its work count."""

    def __init__(
        self,
        plan: DiscretePlan,
        score: Score,
        allowed: Sequence[list[int]],
        limit: int,
        budget: Budget | None,
    ) -> None:
        self.plan = plan
        self.score_fn = score
        self.allowed = allowed
        self.limit = limit
        self.budget = budget
        self.count = 0
        self.K = plan.num_transitions
        self.seen: dict[bytes, Trial] = {}

    def score(self, modes: np.ndarray) -> Trial:
        key = modes.tobytes()
        if key in self.seen:  # a switch moved back and forth: scored already, costs no work
            return self.seen[key]
        self.count += 1
        trial = self.score_fn(DiscretePlan(self.plan.required, modes, self.plan.length))
        self.seen[key] = trial
        return trial

    def moves(self, modes: np.ndarray, k0: int, window: int | None = None) -> Iterator[np.ndarray]:
        """Single changes (nearest before ``k0`` first), then a switch moved one step; with a
        ``window``, only at steps ``k0 - window .. k0 + 1``."""
        K, allowed = self.K, self.allowed
        order = list(range(min(k0, K), 0, -1)) + list(range(min(k0, K) + 1, K + 1))
        if window is not None:
            order = [j for j in order if k0 - window <= j <= k0 + 1]
        for j in order:
            for q in allowed[j]:
                if q != modes[j]:
                    trial = modes.copy()
                    trial[j] = q
                    yield trial
        for j in order:
            if j < K and modes[j] != modes[j + 1]:
                if modes[j + 1] in allowed[j] and modes[j] in allowed[j + 1]:
                    trial = modes.copy()
                    trial[j], trial[j + 1] = modes[j + 1], modes[j]
                    yield trial

    def starts(self, proposed: Trial, num_modes: int) -> Trial:
        """The best of the proposed modes and each mode held throughout."""
        best = proposed
        allowed = self.allowed
        if any(not a for a in allowed[1:]):
            return best
        first_mode = int(proposed.modes[0])
        for q in range(num_modes):
            modes = np.array([first_mode] + [q if q in a else a[0] for a in allowed[1:]], dtype=int)
            if np.array_equal(modes, proposed.modes):
                continue
            trial = self.score(modes)
            if trial.done:
                return trial
            if trial.key[0] >= 0 and trial.key > best.key:
                best = trial
        return best

    def descend(self, current: Trial) -> Trial:
        """First-improvement descent from ``current``: a local optimum or a trial that is done."""
        widened = False
        while self.count < self.limit:
            if self.budget is not None:
                self.budget.check("the mode search")
            improved = False
            # Among sequences the plan LP meets, the room's moves stay near the step that is
            # short of it (a look serves the steps just after it); at a local optimum of the
            # window, every step is tried once before the descent stops.
            window = ROOM_WINDOW if current.key[0] == 1 and not widened else None
            for modes in self.moves(current.modes, current.focus, window):
                if self.count >= self.limit:
                    break
                trial = self.score(modes)
                if trial.done:
                    return trial
                if trial.key[0] >= 0 and _improves(trial.key, current.key):
                    current, improved = trial, True
                    break
            if improved:
                widened = False
            elif window is not None:
                widened = True
            else:
                break
        return current

    def fit(self, previous: np.ndarray) -> np.ndarray | None:
        """``previous`` modes cut or extended (last mode held) to this plan, if allowed."""
        length = self.plan.length
        tail = np.full(max(0, length - previous.shape[0]), previous[-1])
        fitted = np.concatenate([previous[:length], tail]).astype(int)
        fitted[0] = self.plan.modes[0]
        if not all(int(fitted[k]) in self.allowed[k] for k in range(1, length)):
            return None
        return fitted

    def restart(self, previous: np.ndarray, best: Trial) -> Trial | None:
        """A descent from the last search's best modes, cut or extended (last mode held)."""
        fitted = self.fit(previous)
        if fitted is None:
            return None
        if np.array_equal(fitted, best.modes) or self.count >= self.limit:
            return None
        trial = self.score(fitted)
        if trial.done or trial.key[0] < 0:
            return trial if trial.done else None
        return self.descend(trial)
