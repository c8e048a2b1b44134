"""Exact PrSTL semantics on a trajectory (paper Section II-C) and a quantitative margin.

The monitor is the ground truth of the project: every plan the solver returns passes it.

Semantics on a finite trajectory of length ``L = N + 1`` (strong reading: an index ``>= L``
satisfies nothing):

- ``pi^Q`` holds at ``k`` iff ``k == 0`` or ``q_{k-1}`` is in ``Q`` (the mode used to arrive);
- a chance constraint holds iff ``h' mean_k + c + Phi^-1(1-eps) sqrt(h' cov_k h) <= 0``;
- a joint chance constraint ``P[x in region] >= 1 - eps`` holds iff Boole's inequality
  certifies it: the faces' violation probabilities sum to at most ``eps`` (sound: the region
  then holds with probability ``>= 1 - eps``; :func:`idstlpy.chance.joint_slack`);
- ``f1 U[a,b] f2`` at ``k``: some ``k'`` in ``[k+a, k+b]`` has ``f2`` and ``f1`` holds on
  ``[k+a, k')``;
- ``f1 R[a,b] f2`` at ``k``: ``f2`` on all of ``[k+a, k+b]``, or some ``k'`` in the window has
  ``f1`` with ``f2`` on ``[k+a, k']``.

The margin (robustness) replaces truth values by numbers: for a chance constraint the slack
``-(h' mean + c + Phi^-1(1-eps) sd)``, min over conjunctions, max over disjunctions, ``+inf`` /
``-inf`` for mode atoms; for a joint chance constraint the largest distance every face can move
inwards with the constraint still certified. It is ``>= 0`` exactly when the formula holds, and
its magnitude is the distance of the tightest deciding constraint from its bound.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._checks import as_int
from .chance import joint_slack, slack
from .errors import DimensionError, InvalidTypeError
from .formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil
from .trajectory import ProbabilisticTSTrajectory

__all__ = [
    "atom_margins",
    "formula_margins",
    "robustness",
    "satisfies",
    "MonitorReport",
    "monitor",
]

_NEG = -np.inf


def atom_margins(
    ap: STLAtomicProposition, means: np.ndarray, covs: np.ndarray, actions: np.ndarray
) -> np.ndarray:
    """Margin of one atomic proposition at every step, shape (L,).

    Parameters
    ----------
    ap : STLAtomicProposition
        The proposition (chance constraints and/or a mode set).
    means : ndarray, shape (L, n)
        Belief means along the trajectory.
    covs : ndarray, shape (L, n, n)
        Belief covariances along the trajectory.
    actions : ndarray of int, shape (L-1,)
        Mode applied at each step (the mode used to arrive at step ``k`` is ``actions[k-1]``).

    Returns
    -------
    ndarray, shape (L,)
        The smallest chance-constraint slack (joint constraints: :func:`~idstlpy.chance.joint_slack`)
        at each step (``+inf`` without predicates),
        ``-inf`` where the arriving mode is not allowed or the proposition is false.
    """
    L = means.shape[0]
    if ap.is_false:
        return np.full(L, _NEG)
    out = np.full(L, np.inf)
    if ap.predicates:
        cone = ap.cone
        if cone.dim != means.shape[1]:
            raise DimensionError(
                f"proposition {ap.name or ap} is over a {cone.dim}-dimensional variable, "
                f"the trajectory has state dimension {means.shape[1]}"
            )
        k = ap.num_single
        if k:
            out = np.min(slack(cone.H[:k], cone.c[:k], cone.z[:k], means, covs), axis=1)
        for joint in ap.joints:  # judged as a whole, not at the solver's shares
            out = np.minimum(out, joint_slack(joint.H, joint.c, joint.eps, means, covs))
    if ap.modes is not None and L > 1:
        allowed = np.isin(actions, np.fromiter(ap.modes, dtype=int, count=len(ap.modes)))
        out[1:] = np.where(allowed, out[1:], _NEG)
    return out


def _shift(arr: np.ndarray, d: int) -> np.ndarray:
    """``arr[k + d]`` for every ``k`` (``-inf`` past the end); time is axis 0 (a batch may follow)."""
    L = arr.shape[0]
    out = np.full(arr.shape, _NEG)
    if d < L:
        out[: L - d] = arr[d:]
    return out


def _until(r1: np.ndarray, r2: np.ndarray, a: int, b: int) -> np.ndarray:
    # best[k] = max over d in [a, b] of min(r2[k+d], min of r1 over [k+a, k+d)), past the end -inf.
    # In place on the first L - d entries: there shift(r, d) is r[d:]; beyond, the shifted value
    # is -inf, which leaves best unchanged and makes prefix -inf where it is never read again.
    L = r1.shape[0]
    shape = np.broadcast_shapes(r1.shape, r2.shape)
    r1 = np.broadcast_to(r1, shape)
    r2 = np.broadcast_to(r2, shape)
    best = np.full(shape, _NEG)
    prefix = np.full(shape, np.inf)  # min of r1 over [k+a, k+d)
    tmp = np.empty(shape)
    for d in range(a, min(b, L - 1) + 1):
        m = L - d
        np.minimum(r2[d:], prefix[:m], out=tmp[:m])
        np.maximum(best[:m], tmp[:m], out=best[:m])
        np.minimum(prefix[:m], r1[d:], out=prefix[:m])
    return best


def _release(r1: np.ndarray, r2: np.ndarray, a: int, b: int) -> np.ndarray:
    # best[k] = max over d of min(r1[k+d], min of r2 over [k+a, k+d]), or r2 on the whole window.
    L = r1.shape[0]
    shape = np.broadcast_shapes(r1.shape, r2.shape)
    r1 = np.broadcast_to(r1, shape)
    r2 = np.broadcast_to(r2, shape)
    best = np.full(shape, _NEG)
    prefix = np.full(shape, np.inf)  # min of r2 over [k+a, k+d]
    tmp = np.empty(shape)
    for d in range(a, b + 1):
        if d >= L:
            prefix[:] = _NEG  # every index is past the end: prefix is -inf from here on
            break
        m = L - d
        np.minimum(prefix[:m], r2[d:], out=prefix[:m])
        prefix[m:] = _NEG
        np.minimum(r1[d:], prefix[:m], out=tmp[:m])
        np.maximum(best[:m], tmp[:m], out=best[:m])
    return np.maximum(best, prefix)


def formula_margins(formula: STLFormula, atoms: Mapping[int, np.ndarray], length: int) -> np.ndarray:
    """Margin of ``formula`` at every step of a trace, shape (length,).

    Parameters
    ----------
    formula : STLFormula
    atoms : mapping from ``id(ap)`` to the atom's margin array (length,)
        Boolean traces work too: use ``+inf`` for true and ``-inf`` for false. Arrays of shape
        (length, S) monitor a batch of ``S`` traces at once (time on axis 0); every atom array
        then has that shape.
    length : int
        Trace length ``L = N + 1``.

    Returns
    -------
    ndarray, shape (length,) or (length, S)
    """
    memo: dict[int, np.ndarray] = {}
    first = next(iter(atoms.values()), None)
    shape = (length,) if first is None else (length, *np.shape(first)[1:])

    def rec(f: STLFormula) -> np.ndarray:
        key = id(f)
        if key in memo:
            return memo[key]
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = np.full(shape, _NEG)
            elif f.is_true and id(f) not in atoms:
                out = np.full(shape, np.inf)
            else:
                out = np.asarray(atoms[key], dtype=float)
        elif isinstance(f, STLAnd):
            out = np.minimum.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLOr):
            out = np.maximum.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLUntil):
            out = _until(rec(f.left), rec(f.right), f.a, f.b)
        elif isinstance(f, STLRelease):
            out = _release(rec(f.left), rec(f.right), f.a, f.b)
        else:
            raise InvalidTypeError(f"cannot monitor {type(f).__name__}")
        memo[key] = out
        return out

    return rec(formula)


def _trajectory_atoms(traj: ProbabilisticTSTrajectory, formula: STLFormula) -> dict[int, np.ndarray]:
    means, covs, actions = traj.get_mean(), traj.get_cov(), traj.get_action()
    return {id(ap): atom_margins(ap, means, covs, actions) for ap in formula.atomic_propositions()}


def robustness(trajectory: ProbabilisticTSTrajectory, formula: STLFormula, k: int = 0) -> float:
    """Quantitative margin of ``formula`` at step ``k`` (``>= 0`` iff satisfied).

    ``k`` must be ``>= 0``; a step past the end of the trajectory satisfies nothing (``-inf``).

    Parameters
    ----------
    trajectory : ProbabilisticTSTrajectory
        The belief trajectory to monitor.
    formula : STLFormula
        The formula whose margin is computed.
    k : int, default 0
        Step at which the formula is evaluated.

    Returns
    -------
    float
    """
    k = as_int(k, "k", minimum=0)
    L = trajectory.num_of_steps + 1
    if k >= L:
        return _NEG
    return float(formula_margins(formula, _trajectory_atoms(trajectory, formula), L)[k])


def satisfies(trajectory: ProbabilisticTSTrajectory, formula: STLFormula, k: int = 0) -> bool:
    """Whether the trajectory satisfies ``formula`` at step ``k`` (paper: ``beta |=_k phi``).

    Parameters
    ----------
    trajectory : ProbabilisticTSTrajectory
        The belief trajectory to monitor.
    formula : STLFormula
        The formula to check.
    k : int, default 0
        Step at which the formula is evaluated (``>= 0``).

    Returns
    -------
    bool
        ``robustness(trajectory, formula, k) >= 0``.
    """
    return robustness(trajectory, formula, k) >= 0.0


@dataclass(frozen=True)
class MonitorReport:
    """Outcome of monitoring a trajectory.

    Parameters
    ----------
    satisfied : bool
        Whether the formula holds at step 0.
    margin : float
        Robustness at step 0.
    atom_margins : dict[str, ndarray]
        Per atomic proposition (by name, or ``ap<i>``), its margin at every step.
    """

    satisfied: bool
    margin: float
    atom_margins: dict[str, np.ndarray]


def monitor(trajectory: ProbabilisticTSTrajectory, formula: STLFormula) -> MonitorReport:
    """Decide satisfaction and report the margins behind the verdict.

    Parameters
    ----------
    trajectory : ProbabilisticTSTrajectory
        The belief trajectory to monitor.
    formula : STLFormula
        The formula checked at step 0.

    Returns
    -------
    MonitorReport
    """
    aps: Sequence[STLAtomicProposition] = formula.atomic_propositions()
    atoms = _trajectory_atoms(trajectory, formula)
    L = trajectory.num_of_steps + 1
    margin = float(formula_margins(formula, atoms, L)[0])
    named: dict[str, Any] = {}
    for i, ap in enumerate(aps):
        named[ap.name or f"ap{i}"] = atoms[id(ap)]
    return MonitorReport(margin >= 0.0, margin, named)
