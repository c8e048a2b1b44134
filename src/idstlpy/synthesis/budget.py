"""The wall-clock safety cap of one solve (:class:`Budget`).

A leaf of the synthesis layer: every part (encoding, LPs, sampling, covariance floors) takes a
:class:`Budget`, so this module imports only :class:`~idstlpy._deadline.BudgetExceeded` (a leaf of
the model, which the loops of every layer may raise); :mod:`.interfaces` re-exports both.
"""

from __future__ import annotations

import time

from .._deadline import BudgetExceeded

__all__ = ["Budget", "BudgetExceeded"]


class Budget:
    """The overall wall-clock safety cap of one solve.

    Parameters
    ----------
    seconds : float
        The cap, counted from ``start``.
    start : float, optional
        ``time.perf_counter()`` at the first line of ``solve`` (default: now).
    """

    def __init__(self, seconds: float, start: float | None = None) -> None:
        self.start = time.perf_counter() if start is None else start
        self.seconds = seconds
        self.deadline = self.start + seconds

    def elapsed(self) -> float:
        """Seconds since the start."""
        return time.perf_counter() - self.start

    def remaining(self) -> float:
        """Seconds left (may be negative)."""
        return self.deadline - time.perf_counter()

    def expired(self) -> bool:
        """Whether the cap has been reached."""
        return time.perf_counter() >= self.deadline

    def check(self, where: str) -> None:
        """Raise :class:`BudgetExceeded` (naming ``where``) when the cap has been reached."""
        if time.perf_counter() >= self.deadline:
            raise BudgetExceeded(where)
