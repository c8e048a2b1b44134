"""Chance switching: the executed mode of a switched system jumps by a Markov chain (issue 35).

The paper's systems switch only when the plan says so. A *Markov jump* switched system adds the
chance that the mode actually executed differs from the one commanded: an actuator fails and
stays failed, a camera drops a frame, the ground turns slippery. With ``q_k`` the commanded mode
of step ``k`` (the plan's) and ``s_k`` the executed one::

    s_0     ~ initial                            (default: P[q_0, q_0, :], as if s_{-1} = q_0)
    s_{k+1} ~ P[q_{k+1}, s_k, :]                 (row-stochastic in the last axis)
    x_{k+1} = A_{s_k} x_k + B_{s_k} u_k + W_{s_k} w_k,   y_{k+1} = C_{s_k} x_{k+1} + n_{s_k} v

so the law of the executed mode may depend on the command (a camera switched on drops frames,
one switched off never turns on) and on the current executed mode (a failure that persists:
``P[c, f, f] = 1``; a dropout that does not: ``P[c, d, :] = P[c, c, :]``).

``observed`` says whether the executor knows ``s_k`` when it acts (the common case: a robot
knows its camera dropped a frame). Observed: the executor tracks with the gains of ``s_k`` and
its Kalman filter predicts and updates with mode ``s_k``'s model. Not observed: the executor
believes the commanded mode (gains and filter of ``q_k``) while the plant and the sensor are
those of ``s_k``.

The switching is attached to the system (:func:`with_switching`), not to the
:class:`~idstlpy.Problem`: it is a property of the plant, like its matrices, and the system is
what every consumer already receives (``simulate`` and the online executor take a system, not a
problem). A system without it is untouched, so every computation without chance switching is
bit for bit the former one.

This is a model-layer module: it imports only the model (``dynamical_system``, the checks and
the errors).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .dynamical_system import SwitchedSystem
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError

__all__ = ["MarkovSwitching", "mk_markov_switching", "with_switching", "switching_of"]

_ATTR = "_markov_switching"
# Rows may miss 1 by rounding of a user's decimals (0.1 + 0.2 + 0.7); anything larger is a typo.
_ROW_TOL = 1e-9


@dataclass(frozen=True)
class MarkovSwitching:
    """The law of the executed mode (build it with :func:`mk_markov_switching`).

    Attributes
    ----------
    transitions : ndarray, shape (num_commanded, num_modes, num_modes)
        ``transitions[c, i, j]``: probability that the executed mode is ``j`` at a step whose
        commanded mode is ``c``, when it was ``i`` the step before. Read-only.
    observed : bool
        Whether the executor knows the executed mode when it acts (module notes).
    initial : ndarray, shape (num_modes,) or None
        Law of the first executed mode; None: ``transitions[q_0, q_0]`` (the system was in the
        commanded mode before the plan starts).
    """

    transitions: np.ndarray = field(repr=False)
    observed: bool = True
    initial: np.ndarray | None = field(default=None, repr=False)

    @property
    def num_modes(self) -> int:
        """Number of modes of the chain (the system's)."""
        return int(self.transitions.shape[1])

    def first(self, commanded: int) -> np.ndarray:
        """Law (num_modes,) of the executed mode at step 0 when ``commanded`` is ``q_0``."""
        if self.initial is not None:
            return self.initial
        return np.asarray(self.transitions[commanded, commanded])

    def row(self, commanded: int, current: int) -> np.ndarray:
        """Law (num_modes,) of the next executed mode given the next command and the current mode."""
        return np.asarray(self.transitions[commanded, current])

    def sequence_probability(self, commanded: ArrayLike, executed: ArrayLike) -> float:
        """Probability of the executed sequence ``executed`` (N,) under commands ``commanded`` (N,)."""
        q = np.asarray(commanded, dtype=int)
        s = np.asarray(executed, dtype=int)
        if q.shape != s.shape or q.ndim != 1:
            raise DimensionError(
                f"commanded and executed must be sequences of one length, got shapes {q.shape} and {s.shape}"
            )
        if not q.size:
            return 1.0
        p = float(self.first(int(q[0]))[s[0]])
        for k in range(1, q.size):
            p *= float(self.transitions[q[k], s[k - 1], s[k]])
        return p

    def draw(self, commanded: ArrayLike, rng: np.random.Generator, runs: int = 1) -> np.ndarray:
        """Executed sequences (runs, N) drawn under the commands ``commanded`` (N,).

        One uniform per run and step from ``rng`` (inverse CDF), so the draw is reproducible.
        """
        q = np.asarray(commanded, dtype=int)
        N = q.shape[0]
        out = np.empty((runs, N), dtype=int)
        if not N:
            return out
        cum0 = np.cumsum(self.first(int(q[0])))
        out[:, 0] = _inverse_cdf(cum0[None, :], rng.random(runs))
        for k in range(1, N):
            cum = np.cumsum(self.transitions[q[k]], axis=1)  # (num_modes, num_modes)
            out[:, k] = _inverse_cdf(cum[out[:, k - 1]], rng.random(runs))
        return out


def _inverse_cdf(cum: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index ``j`` with ``cum[j-1] <= u < cum[j]`` per row (``cum`` (S, M), ``u`` (S,))."""
    idx = (u[:, None] >= cum).sum(axis=1)
    return np.minimum(idx, cum.shape[1] - 1)  # (a row summing to 1 - 1e-12 against u ~ 1)


def mk_markov_switching(
    transitions: ArrayLike, observed: bool = True, initial: ArrayLike | None = None
) -> MarkovSwitching:
    """Declare chance switching of the executed mode (module notes).

    Parameters
    ----------
    transitions : array_like, shape (num_commanded, num_modes, num_modes) or (num_modes, num_modes)
        ``transitions[c, i, j]``: probability that the executed mode becomes ``j`` at a step
        commanded ``c`` when it was ``i``. Each row ``transitions[c, i, :]`` is a probability
        vector (entries in [0, 1], sum 1 within 1e-9; rows are renormalised). A 2-D matrix
        is the same for every command. ``num_commanded`` must equal ``num_modes`` (a command is
        a mode).
    observed : bool, default True
        Whether the executor knows the executed mode when it acts.
    initial : array_like, shape (num_modes,), optional
        Law of the first executed mode (default: ``transitions[q_0, q_0]``).

    Returns
    -------
    MarkovSwitching

    Raises
    ------
    InvalidTypeError
        When ``transitions`` or ``initial`` is not numeric or ``observed`` not a bool.
    DimensionError
        When ``transitions`` is not (M, M) or (M, M, M), or ``initial`` not (M,).
    InvalidArgumentError
        When an entry is negative, above 1 or not finite, or a row does not sum to 1 (the
        message names the row).
    """
    try:
        P = np.array(transitions, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidTypeError(
            f"transitions must be a numeric array of shape (num_commanded, num_modes, num_modes), "
            f"got {type(transitions).__name__}"
        ) from exc
    if P.ndim == 2:
        P = np.broadcast_to(P, (P.shape[0], *P.shape)).copy()
    if P.ndim != 3 or P.shape[1] != P.shape[2] or P.shape[0] != P.shape[1] or P.shape[1] == 0:
        raise DimensionError(
            "transitions must have shape (num_commanded, num_modes, num_modes) with "
            f"num_commanded = num_modes >= 1 (or a square (num_modes, num_modes)), got {P.shape}"
        )
    _check_stochastic(P, "transitions")
    if not isinstance(observed, (bool, np.bool_)):
        raise InvalidTypeError(f"observed must be True or False, got {type(observed).__name__}")
    P = P / P.sum(axis=2, keepdims=True)
    P.flags.writeable = False
    init: np.ndarray | None = None
    if initial is not None:
        try:
            init = np.array(initial, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InvalidTypeError(
                f"initial must be a probability vector of length {P.shape[1]}, got {type(initial).__name__}"
            ) from exc
        if init.shape != (P.shape[1],):
            raise DimensionError(f"initial must have shape ({P.shape[1]},), got {init.shape}")
        _check_stochastic(init[None, None, :], "initial")
        init = init / init.sum()
        init.flags.writeable = False
    return MarkovSwitching(P, bool(observed), init)


def _check_stochastic(P: np.ndarray, name: str) -> None:
    """Raise naming the first row of ``P`` (c, i, M) that is not a probability vector."""
    if not np.isfinite(P).all():
        raise InvalidArgumentError(f"{name} contains NaN or inf")
    bad = np.argwhere((P < 0) | (P > 1))
    if bad.size:
        c, i, j = (int(v) for v in bad[0])
        where = f"[{j}]" if name == "initial" else f"[{c}, {i}, {j}]"
        raise InvalidArgumentError(f"{name}{where} = {P[c, i, j]:g} is not a probability (in [0, 1])")
    sums = P.sum(axis=2)
    off = np.argwhere(np.abs(sums - 1.0) > _ROW_TOL)
    if off.size:
        c, i = (int(v) for v in off[0])
        row = name if name == "initial" else f"{name}[{c}, {i}, :]"
        raise InvalidArgumentError(
            f"{row} sums to {sums[c, i]:.12g}, must sum to 1 (each row is the law of the next executed mode)"
        )


def with_switching(system: SwitchedSystem, switching: MarkovSwitching | None) -> SwitchedSystem:
    """A copy of ``system`` whose executed mode jumps by ``switching`` (None: without jumps).

    The modes are shared with ``system`` (not copied); ``system`` itself is unchanged.

    Parameters
    ----------
    system : SwitchedSystem
    switching : MarkovSwitching or None
        From :func:`mk_markov_switching`; its number of modes must be the system's.

    Returns
    -------
    SwitchedSystem

    Raises
    ------
    InvalidTypeError
        When an argument has the wrong type.
    DimensionError
        When the chain's number of modes is not the system's.
    """
    if not isinstance(system, SwitchedSystem):
        raise InvalidTypeError(f"system must be made by mk_switched_sys, got {type(system).__name__}")
    if switching is not None and not isinstance(switching, MarkovSwitching):
        raise InvalidTypeError(
            f"switching must be made by mk_markov_switching, got {type(switching).__name__}"
        )
    if switching is not None and switching.num_modes != system.num_modes:
        raise DimensionError(f"switching has {switching.num_modes} modes, the system has {system.num_modes}")
    out = copy.copy(system)
    setattr(out, _ATTR, switching)
    return out


def switching_of(system: object) -> MarkovSwitching | None:
    """The chance switching attached to ``system`` by :func:`with_switching` (None: none)."""
    found = getattr(system, _ATTR, None)
    return found if isinstance(found, MarkovSwitching) else None
