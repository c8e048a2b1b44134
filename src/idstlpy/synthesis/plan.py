"""Discrete plans: which propositions must hold at which step, extracted from a label trace.

A SAT model (or a realised trace) says which propositions are claimed at every step. Because
PrSTL has no negation, the formula only needs a *witness*: a set of (proposition, step) pairs
whose truth implies the formula. :func:`~idstlpy.label_semantics.extract_witness` (model layer,
re-exported here with :func:`~idstlpy.label_semantics.evaluate_bool`) picks one by walking the
formula top down (one true disjunct, one until-witness step), so the continuous teacher receives
only the constraints that matter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..formulas import STLFormula
from ..label_semantics import evaluate_bool, extract_witness

if TYPE_CHECKING:  # the abstraction imports this module
    from ..trajectory import ProbabilisticTSTrajectory
    from .abstraction import Abstraction

__all__ = ["DiscretePlan", "evaluate_bool", "extract_witness", "trajectory_plan"]


@dataclass
class DiscretePlan:
    """A candidate from the proposer.

    Attributes
    ----------
    required : ndarray of bool, shape (n_atoms, L)
        ``required[i, k]``: proposition ``i`` must hold at step ``k``.
    modes : ndarray of int, shape (L,)
        ``modes[k]`` (``k >= 1``): mode used to arrive at ``k``, as proposed (``modes[0] = -1``).
    length : int
        ``L``: number of steps the plan spans (``L - 1`` transitions).
    """

    required: np.ndarray
    modes: np.ndarray
    length: int

    @property
    def num_transitions(self) -> int:
        """``L - 1``."""
        return self.length - 1

    def requirements(self) -> list[tuple[int, int]]:
        """``(step, atom)`` pairs, sorted by step."""
        atoms, steps = np.nonzero(self.required)
        order = np.lexsort((atoms, steps))
        return [(int(steps[o]), int(atoms[o])) for o in order]


def trajectory_plan(
    formula: STLFormula, abstraction: Abstraction, traj: ProbabilisticTSTrajectory
) -> DiscretePlan | None:
    """The requirements a belief trajectory meets, as the discrete plan of its earliest witness.

    Labels every step of ``traj`` with the propositions its belief satisfies (``abstraction.truth``)
    and keeps the witness of ``formula`` those labels contain (earliest until-steps), with the
    trajectory's modes: what the plan LP must keep when it moves the trajectory.

    Parameters
    ----------
    formula : STLFormula
    abstraction : Abstraction
        Its ``truth(mean, cov, mode)`` and ``index``.
    traj : ProbabilisticTSTrajectory
        ``K`` steps.

    Returns
    -------
    DiscretePlan or None
        ``None`` when the trajectory's labels satisfy no witness of the formula.
    """
    modes = np.concatenate([[-1], traj.get_action()]).astype(int)
    truth = np.stack(
        [
            abstraction.truth(mu, cov, int(q))
            for mu, cov, q in zip(traj.get_mean(), traj.get_cov(), modes, strict=True)
        ],
        axis=1,
    )
    witness = extract_witness(formula, truth, abstraction.index, prefer_late=False)
    if witness is None:
        return None
    required, L = witness
    return DiscretePlan(required[:, :L], modes[:L], L)
