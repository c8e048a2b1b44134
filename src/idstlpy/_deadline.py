"""The exception that unwinds a solve whose wall-clock cap was hit.

This module is a leaf: every layer may import it (the synthesis raises it through
:class:`~idstlpy.synthesis.budget.Budget`; the loop catches it).
"""

from __future__ import annotations

__all__ = ["BudgetExceeded"]


class BudgetExceeded(Exception):
    """Internal: the overall wall-clock cap was hit (caught by the loop, never seen by users)."""

    def __init__(self, where: str) -> None:
        super().__init__(where)
        self.where = where
