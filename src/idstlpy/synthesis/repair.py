"""One trust-region repair loop: what the execution room, the objectives' refiner and the
closed-loop certification share.

A repair starts from a plan the monitor accepts (its MLO roll-out) and, round after round,
proposes a step inside a trust region (an LP: the plan LP's rows with the covariances frozen, or
linearised, around the current plan), re-rolls the exact belief dynamics, and keeps the moved
plan only if the monitor still accepts it and its score improved; otherwise the trust region
shrinks. The rounds are a work budget (the same problem gives the same plan); a deadline (the
solve's time limit) stops them, and the plan so far is returned: a repair is anytime.

What differs between the repairs is a :class:`RepairSteps`: the state they carry (the plan and
its score), when nothing is left to repair, the first trust region, the step's LP, what
accepting a step means, and when failed rounds mean stop. The three instances are
:func:`.room.give_room` (score: the execution room), :func:`.objectives.refine` (an objective,
keeping the room) and :func:`.certify.certify` (the predicted true state's margin).
"""

from __future__ import annotations

import logging
import time
from typing import Protocol, TypeVar

__all__ = ["STOP", "RepairSteps", "Stop", "repair"]

logger = logging.getLogger(__name__)

S = TypeVar("S")
"""A repair's state: the current plan and what it is judged by."""
P = TypeVar("P")
"""A proposal: what a step's LP gives (controls, a moved plan, ...)."""

NO_DEADLINE = 1e9
"""The time (s) a round's LP is given when the repair has no deadline."""


class Stop:
    """A proposal that ends the repair: nothing more can be tried (:data:`STOP`)."""

    def __repr__(self) -> str:
        return "STOP"


STOP = Stop()
"""What :meth:`RepairSteps.propose` returns when the repair should stop now (no plan to step
from, or the LP promises too little to go on)."""


class RepairSteps(Protocol[S, P]):
    """The parts of one repair (module notes); an instance may count its own work.

    Attributes
    ----------
    name : str
        For the log.
    """

    name: str

    def done(self, state: S) -> bool:
        """Whether ``state`` needs no more repair (checked before every round and at the end)."""
        ...

    def first_trust(self, state: S) -> float:
        """The trust region's radius at the first round (infinite: none)."""
        ...

    def propose(self, state: S, trust: float, left: float) -> P | Stop | None:
        """One step's LP from ``state`` within ``trust``, its LP given ``left`` seconds.

        A proposal; ``None`` when the LP found none (the round failed); :data:`STOP`."""
        ...

    def accept(self, state: S, proposal: P, trust: float) -> S | None:
        """The state after the proposal when it is kept (the monitor accepts it and it
        improves on ``state``), else ``None`` (the round failed)."""
        ...

    def stuck(self, state: S, failures: int) -> bool:
        """After a failed round (``failures`` in a row): stop (True) or shrink the region."""
        ...


def repair(
    steps: RepairSteps[S, P],
    state: S,
    rounds: int,
    *,
    deadline: float | None = None,
    shrink: float = 0.5,
) -> S:
    """Run the trust-region repair loop (module notes) from ``state``.

    Parameters
    ----------
    steps : RepairSteps
        The repair's parts.
    state : S
        The starting state (a plan the monitor accepts).
    rounds : int
        Work budget: proposals (LP rounds) at most.
    deadline : float, optional
        ``time.perf_counter()`` value after which no round starts; each round's LP is given the
        time left (:data:`NO_DEADLINE` seconds without one).
    shrink : float
        Factor of the trust region after a failed round.

    Returns
    -------
    S
        The last state kept (``state`` itself when no round helped).
    """
    trust: float | None = None
    failures = 0
    spent = 0
    while not steps.done(state) and spent < rounds:
        if trust is None:
            trust = steps.first_trust(state)
        left = NO_DEADLINE if deadline is None else deadline - time.perf_counter()
        if left <= 0:
            logger.info("%s: the time limit stops the rounds; the plan so far is kept", steps.name)
            break
        spent += 1
        proposal = steps.propose(state, trust, left)
        if isinstance(proposal, Stop):
            break
        if proposal is not None:
            kept = steps.accept(state, proposal, trust)
            if kept is not None:
                state, failures = kept, 0
                continue
        failures += 1
        if steps.stuck(state, failures):
            break
        trust *= shrink
    return state
