"""The eager MILP's data: what one model is built from (:class:`MILPSpec`), its column blocks
(:class:`Columns`) and its row blocks as they are built (:class:`RowBlocks`).

A leaf of the MILP modules: :mod:`.milp_model` builds the model from them and :mod:`.milp_faces`
adds the chance constraints' rows to them (:mod:`.milp_model` re-exports all three).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix

from .bmc import BMCEncoder
from .interfaces import Budget
from .plan_lp import PlanLPContext

if TYPE_CHECKING:
    from .options import Objective

__all__ = ["Columns", "MILPSpec", "RowBlocks"]


@dataclass(frozen=True)
class MILPSpec:
    """What one eager MILP is built from.

    Attributes
    ----------
    enc : BMCEncoder
        The proposer's current encoding (its proven clauses; abandoned ones are switched off).
    context : PlanLPContext
        The system, control domain, prior, abstraction and scaling (as for every plan LP).
    budget : Budget
    objective : {None, "effort", "margin", "time"}
    effort_weights : ndarray, shape (m,), optional
        Per-input weights of ``"effort"`` (default ones).
    """

    enc: BMCEncoder
    context: PlanLPContext
    budget: Budget
    objective: Objective | None = None
    effort_weights: np.ndarray | None = None


@dataclass(frozen=True)
class Columns:
    """The model's column blocks: letters and gates, means, inputs, margin, absolute inputs."""

    nb: int
    nx: int
    nu: int
    nt: int
    na: int

    @property
    def tcol(self) -> int:
        """The margin's column (when ``nt``)."""
        return self.nb + self.nx + self.nu

    @property
    def acol(self) -> int:
        """The first absolute-input column (when ``na``)."""
        return self.tcol + self.nt

    @property
    def nvar(self) -> int:
        """Columns in all."""
        return self.acol + self.na

    @property
    def inputs(self) -> slice:
        """The scaled inputs' columns."""
        return slice(self.nb + self.nx, self.nb + self.nx + self.nu)


@dataclass
class RowBlocks:
    """The model's row blocks as they are built, with their lower and upper sides."""

    blocks: list[csr_matrix] = field(default_factory=list)
    lo: list[np.ndarray] = field(default_factory=list)
    hi: list[np.ndarray] = field(default_factory=list)

    @property
    def count(self) -> int:
        return sum(b.shape[0] for b in self.blocks)

    def add(self, block: csr_matrix, lo: np.ndarray, hi: np.ndarray) -> None:
        self.blocks.append(block)
        self.lo.append(lo)
        self.hi.append(hi)
