"""The typed contracts between the parts of the synthesis core.

- A **proposer** offers discrete plans (:class:`~.plan.DiscretePlan`) at growing depths, takes
  *proven* conflicts as blocking clauses, sets abandoned candidates aside without treating them
  as proofs, and tells, when it runs dry, whether that is a proof.
- A **teacher** decides a candidate: :class:`Found` (controls), :class:`Refuted` (a conflict
  with its proof: only this may become a clause) or :class:`Unknown` (why it gave up). It
  declares whether it decides a problem exactly, and has hooks for the loop's other steps:
  guiding the proposer, rescuing a refuted candidate, hearing of a plan below target.
- A :class:`~.budget.Budget` carries the wall-clock safety cap from the first line of ``solve``
  to every part (encoding, LPs, sampling); :class:`~.budget.BudgetExceeded` unwinds to the loop
  when it is hit (both in the leaf :mod:`.budget`, re-exported here).

The parts import this module; it imports the plan type and the budget.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from .budget import Budget, BudgetExceeded
from .plan import DiscretePlan

if TYPE_CHECKING:
    from ..problem import Problem
    from .bmc import BMCEncoder
    from .proofs import Proof
    from .results import SolveStats

__all__ = [
    "Budget",
    "BudgetExceeded",
    "Conflict",
    "Found",
    "Proposer",
    "ProposerDry",
    "Refuted",
    "Teacher",
    "Unknown",
    "Verdict",
]


@dataclass
class Conflict:
    """A set of requirements no plan can meet together, with the modes that shaped them.

    Attributes
    ----------
    requirements : list of (step, atom)
        ``(k, i)``: proposition ``i`` at step ``k``.
    modes : ndarray of int, shape (K + 1,) or None
        ``modes[k]`` for ``1 <= k <= K`` (the modes that lead up to the last requirement) when
        the conflict depends on them; ``None`` when it holds for every mode sequence.
    proof : str
        What proves it (e.g. "Farkas certificate of the plan LP").
    certificate : Proof, optional
        How to build its checkable justification (:mod:`.proofs`); ``None``: none kept.
    """

    requirements: list[tuple[int, int]]
    modes: np.ndarray | None
    proof: str
    certificate: Proof | None = field(default=None, repr=False, compare=False)


@dataclass
class Found:
    """A teacher's plan: modes and controls (the loop re-rolls and monitors them)."""

    actions: np.ndarray
    controls: np.ndarray
    how: str
    exact: bool = False
    """True when the teacher's path is exact (the plan LP without state-dependent noise)."""
    searched: bool = False
    """The teacher searched the candidate's modes (its best for the requirement set): should the
    plan be abandoned (below the execution target), the requirement set is set aside for every
    mode sequence (not a proof), as :attr:`Refuted.set_aside`."""


@dataclass
class Refuted:
    """A teacher's proof that the candidate cannot be met."""

    conflict: Conflict
    set_aside: bool = False
    """Also set the candidate's requirement set aside for every mode sequence (not a proof): the
    teacher searched the modes for it and found none (issue 24)."""


@dataclass
class Unknown:
    """A teacher gave up: not a proof of anything."""

    why: str
    hint_means: np.ndarray | None = field(default=None, repr=False)
    # What the teacher got closest to: (actions (k,), controls (k, m), progress); not a plan.
    closest: tuple[np.ndarray, np.ndarray, float] | None = field(default=None, repr=False)
    budgeted: bool = False
    """True when the teacher gave up for want of work (a budget option may change the answer)."""


Verdict = Found | Refuted | Unknown


@dataclass
class ProposerDry:
    """The proposer has no candidate left.

    Attributes
    ----------
    proven : bool
        True when only proven clauses exclude every plan (then no plan exists); False when
        abandoned candidates or the plan-length cap stand in the way.
    reason : str
    aside : bool
        Only candidates set aside without a proof stand in the way.
    """

    proven: bool
    reason: str
    aside: bool = False
    """True when only candidates set aside without a proof stand in the way (the loop says which
    and why, :meth:`~.context.SolveContext.aside_reason`)."""


class Proposer(Protocol):
    """Offers discrete plans; learns proven conflicts; sets abandoned candidates aside.

    Every member the loop and its parts use (:mod:`.cegis`, :mod:`.eager`, the belief sampler)
    is declared here, and they are typed against this protocol, not against an implementation.
    """

    @property
    def hard(self) -> Sequence[Sequence[object]]:
        """The proven clauses learnt so far, oldest first (the eager switch reads their sizes)."""
        ...

    @property
    def bound(self) -> int:
        """The current encoding covers plans of at most ``bound`` steps (the states ``0..bound``)."""
        ...

    @property
    def cap(self) -> int:
        """The largest ``bound`` allowed (the formula's horizon, or ``max_plan_length``)."""
        ...

    @property
    def H(self) -> int:
        """The formula's horizon: a proposer dry at this bound is a proof."""
        ...

    @property
    def sat_calls(self) -> int:
        """SAT calls made so far (for the statistics)."""
        ...

    def propose(self) -> DiscretePlan | ProposerDry:
        """The next candidate (shortest first), or why there is none."""
        ...

    def block(self, conflict: Conflict) -> None:
        """Forbid a *proven* conflict for good."""
        ...

    def abandon(self, plan: DiscretePlan) -> None:
        """Set a candidate aside without a proof (it may count against ``infeasible``)."""
        ...

    def set_aside(self, plan: DiscretePlan) -> None:
        """Set a candidate's requirements aside for every mode sequence, without a proof."""
        ...

    def guide(self, plan: DiscretePlan, truth: np.ndarray) -> None:
        """Prefer, in the next searches, the labels ``truth`` (n_atoms, K + 1) a teacher saw."""
        ...

    def grow(self) -> bool:
        """Cover longer plans (a larger ``bound``); False when at ``cap``."""
        ...

    def complete(self, truth: np.ndarray, modes: np.ndarray) -> DiscretePlan | None:
        """A plan that extends a realised prefix, or ``None`` if none is left."""
        ...

    def export(self) -> BMCEncoder:
        """The current encoding with its proven clauses, for an eager model."""
        ...

    def close(self) -> None:
        """Free the proposer's solver."""
        ...


class Teacher(Protocol):
    """Decides candidates of the problems it applies to.

    Besides :meth:`teach`, a teacher has hooks the loop calls at fixed points of the figure; their
    defaults do nothing, so a teacher subclasses this protocol and overrides the ones it needs.
    """

    name: str

    def applies(self, problem: Problem) -> bool:
        """Whether this teacher has anything to say about ``problem``."""
        ...

    def exact(self, problem: Problem) -> bool:
        """Whether its Found / Refuted decide every candidate of ``problem`` (never Unknown)."""
        ...

    def teach(self, plan: DiscretePlan, budget: Budget, stats: SolveStats) -> Verdict:
        """Decide ``plan`` within ``budget``; count work in ``stats``."""
        ...

    def guide(self, proposer: Proposer, plan: DiscretePlan) -> None:
        """After teaching ``plan``: steer the proposer's next searches (default: nothing)."""
        return None

    def rescue(self, plan: DiscretePlan, refuted: Refuted, budget: Budget, stats: SolveStats) -> Verdict:
        """Take over a candidate a teacher refuted (default: the refutation stands).

        A teacher that chooses what a refutation was about (the modes, say) may search the
        candidate itself; anything but ``refuted`` returned here replaces the refutation.
        """
        return refuted

    def below_target(self) -> None:
        """Hear that a verified plan was set aside below the execution target (default: nothing)."""
        return None

    def searches_modes(self, problem: Problem) -> bool:
        """Whether this teacher searches each candidate's modes for the plan predicted to hold
        best when executed (its requirement set is then not offered again with other modes, and
        the loop's search after a plan below target can be short; default: no)."""
        return False
