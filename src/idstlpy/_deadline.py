"""The solve's wall-clock cap, visible to the loops deep below the synthesis.

A solve's ``time_limit`` must be kept on every path, also inside work the synthesis hands to the
model and executor layers (the predicted execution of a candidate plan: its moments and model
samples, step by step). Rather than widening every signature between a solve and those loops,
the synthesis enters a :func:`scope` with its deadline and the loops call :func:`check` once per
step: a no-op outside any scope (``validate``, ``predict_closed_loop`` called by a user), and a
:class:`BudgetExceeded` once the innermost deadline has passed. The deadline lives in a
:mod:`contextvars` variable, so concurrent solves in threads (a re-solve beside a robot's loop)
each see their own.

This module is a leaf: every layer may import it.
"""

from __future__ import annotations

import contextvars
import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["BudgetExceeded", "check", "remaining", "scope"]


class BudgetExceeded(Exception):
    """Internal: the overall wall-clock cap was hit (caught by the loop, never seen by users)."""

    def __init__(self, where: str, ahead: str = "") -> None:
        super().__init__(where)
        self.where = where
        self.ahead = ahead
        """Set when the cap was not reached yet but the next piece of work (named) would not fit
        in the time left: the solve stops before starting it."""


_DEADLINE: contextvars.ContextVar[float | None] = contextvars.ContextVar("idstlpy_deadline", default=None)


@contextmanager
def scope(deadline: float) -> Iterator[None]:
    """Run the block under ``deadline`` (a ``time.perf_counter()`` value); a nested scope keeps
    the earlier of its own and the enclosing one."""
    outer = _DEADLINE.get()
    token = _DEADLINE.set(deadline if outer is None else min(outer, deadline))
    try:
        yield
    finally:
        _DEADLINE.reset(token)


def check(where: str) -> None:
    """Raise :class:`BudgetExceeded` (naming ``where``) when the current scope's deadline has
    passed; nothing outside a scope."""
    deadline = _DEADLINE.get()
    if deadline is not None and time.perf_counter() >= deadline:
        raise BudgetExceeded(where)


def remaining() -> float:
    """Seconds left in the current scope (``inf`` outside any scope; may be negative)."""
    deadline = _DEADLINE.get()
    return float("inf") if deadline is None else deadline - time.perf_counter()
