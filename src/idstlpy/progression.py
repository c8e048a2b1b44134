"""Formula progression: what a formula still asks of a trajectory once a prefix has happened.

A receding-horizon executor that re-plans at step ``k`` must not plan for the original formula
from scratch: an until may be half-way (its left operand held for ``k`` steps), a hold may be in
progress, a deadline has moved closer. :func:`progress` rewrites the formula over an observed
prefix ``X_0 .. X_k`` (with the modes ``q_0 .. q_{k-1}``) into the obligation on the suffix.

Convention at the split step
----------------------------
The prefix and the suffix share the belief ``X_k``: the prefix is ``xi[:k+1]`` (``k + 1``
beliefs, ``k`` modes) and the suffix is ``xi[k:]`` (it starts at ``X_k``). On the suffix, step 0
is ``X_k`` but the mode used to arrive there is not part of it, so a mode predicate holds there
vacuously (paper Section II-C: ``pi^Q`` holds at step 0). The prefix knows that mode
(``q_{k-1}``), so :func:`progress` decides *everything* at ``X_k`` from the prefix, chance
constraints included, and the returned formula only looks at suffix steps ``>= 1``, unless it is
the constant :data:`~idstlpy.formulas.TRUE` or :data:`~idstlpy.formulas.FALSE`. The guarantee::

    satisfies(xi, phi)  ==  satisfies(xi[k:], progress(phi, xi[:k+1]))

for every trajectory ``xi`` with at least ``k + 1`` beliefs (``tests/test_progression.py``
checks it against the brute-force monitor). A re-plan from ``X_k`` therefore solves the
progressed formula from the current belief, and any plan satisfying it completes the prefix
into a trajectory that satisfies the original formula.

How
---
One step of progression (classical for LTL / MTL, here with the paper's intervals and the
strong finite reading of :mod:`idstlpy.semantics`, where an index past the end satisfies
nothing) rewrites a formula at step ``j`` into one at step ``j + 1``, given the truth of the
atomic propositions at ``j``::

    prog(p)                 = TRUE or FALSE  (p evaluated at j)
    prog(f & g), prog(f | g)  componentwise, simplified
    prog(f1 U[a,b] f2)      = f1 U[a-1,b-1] f2                                   (a > 0)
                            = prog(f2) | (prog(f1) & f1 U[0,b-1] f2)             (a = 0 < b)
                            = prog(f2)                                           (a = b = 0)
    prog(f1 R[a,b] f2)      = f1 R[a-1,b-1] f2                                   (a > 0)
                            = prog(f2) & (prog(f1) | f1 R[0,b-1] f2)             (a = 0 < b)
                            = prog(f2)                                           (a = b = 0)

(``f1 U[a,b] f2`` needs ``f1`` only from ``k + a`` on, so the unfolding at ``a = 0`` is exact.)
After the ``k + 1`` steps ``0 .. k`` the formula speaks about step ``k + 1``; it is moved back one
step (``next``) by adding 1 to the interval of every outermost temporal operator (the progressed
formula is a conjunction / disjunction of temporal operators: every atom at the current step has
become a constant). A constant reached on the way is returned at once: the prefix decided.

Sub-formulas are shared, not copied: the atomic propositions of the result are the original
objects (the solver keys its letters by ``id``), and equal operands of a conjunction or
disjunction are merged (formulas compare structurally), so the progressed formula stays as small
as the obligations it carries.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from .errors import InvalidTypeError
from .formulas import (
    FALSE,
    TRUE,
    STLAnd,
    STLAtomicProposition,
    STLFormula,
    STLOr,
    STLRelease,
    STLUntil,
)
from .semantics import atom_margins
from .trajectory import ProbabilisticTSTrajectory

__all__ = ["progress", "progress_step"]


def _junction(kind: type, parts: Iterable[STLFormula]) -> STLFormula:
    """``STLAnd`` / ``STLOr`` of ``parts`` with constants absorbed and equal operands merged.

    The absorbing constant is FALSE for a conjunction and TRUE for a disjunction; the neutral one
    is dropped. Nested junctions of the same kind are flattened (their order kept).
    """
    absorbing, neutral = (FALSE, TRUE) if kind is STLAnd else (TRUE, FALSE)
    out: dict[STLFormula, None] = {}  # insertion-ordered set: the result is deterministic
    for p in parts:
        if p is absorbing:
            return absorbing
        if p is neutral:
            continue
        for q in p.children if isinstance(p, kind) else (p,):
            out.setdefault(q, None)
    items = _subsume(list(out), conjunction=kind is STLAnd)
    if not items:
        return neutral
    if len(items) == 1:
        return items[0]
    return kind(items)  # type: ignore[no-any-return]


def _subsume(items: list[STLFormula], conjunction: bool) -> list[STLFormula]:
    """Merge temporal operands that differ only in the end ``b`` of their interval.

    With the same operands and start ``a``, ``f1 U[a,b] f2`` implies ``f1 U[a,b'] f2`` and
    ``f1 R[a,b'] f2`` implies ``f1 R[a,b] f2`` for ``b <= b'`` (also under the strong finite
    reading). A conjunction keeps the strongest of each group, a disjunction the weakest: the
    holds in progress of ``F G`` formulas otherwise pile up as ``G[1,20] t | G[1,21] t | ...``.
    """
    # Per group: where its representative sits in ``out``, and the representative itself.
    groups: dict[tuple[Any, ...], tuple[int, STLUntil | STLRelease]] = {}
    out: list[STLFormula] = []
    for f in items:
        if not isinstance(f, STLUntil | STLRelease):
            out.append(f)
            continue
        key = (type(f), f.a, f.left, f.right)
        if key not in groups:
            groups[key] = (len(out), f)
            out.append(f)
            continue
        i, g = groups[key]
        # The stronger of the two: the smaller b for until, the larger for release.
        stronger_is_smaller = isinstance(f, STLUntil)
        f_stronger = (f.b < g.b) == stronger_is_smaller
        if f_stronger == conjunction:
            out[i] = f
            groups[key] = (i, f)
    return out


def progress_step(formula: STLFormula, truth: dict[int, bool]) -> STLFormula:
    """One step of progression: the formula at step ``j + 1`` equivalent to ``formula`` at ``j``.

    Parameters
    ----------
    formula : STLFormula
        The obligation at step ``j``.
    truth : dict
        ``id(ap) -> bool``: whether each atomic proposition of ``formula`` holds at step ``j``
        (the constants :data:`TRUE` / :data:`FALSE` need no entry).

    Returns
    -------
    STLFormula
        :data:`TRUE` or :data:`FALSE` when step ``j`` decides the formula, else the obligation
        at step ``j + 1`` (exact when step ``j + 1`` exists; see the module notes).

    Raises
    ------
    InvalidTypeError
        For a node that is not a PrSTL formula, or an atomic proposition missing from ``truth``.
    """
    memo: dict[int, STLFormula] = {}  # shared sub-formulas are progressed once per step

    def rec(f: STLFormula) -> STLFormula:
        key = id(f)
        if key in memo:
            return memo[key]
        out: STLFormula
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = FALSE
            elif f is TRUE:
                out = TRUE
            elif key not in truth:
                raise InvalidTypeError(f"no truth value given for the proposition {f.name or f}")
            else:
                out = TRUE if truth[key] else FALSE
        elif isinstance(f, STLAnd | STLOr):
            out = _junction(type(f), [rec(c) for c in f.children])
        elif isinstance(f, STLUntil):
            if f.a > 0:
                out = STLUntil(f.left, f.a - 1, f.b - 1, f.right)
            elif f.b == 0:
                out = rec(f.right)
            else:
                later = _junction(STLAnd, [rec(f.left), STLUntil(f.left, 0, f.b - 1, f.right)])
                out = _junction(STLOr, [rec(f.right), later])
        elif isinstance(f, STLRelease):
            if f.a > 0:
                out = STLRelease(f.left, f.a - 1, f.b - 1, f.right)
            elif f.b == 0:
                out = rec(f.right)
            else:
                later = _junction(STLOr, [rec(f.left), STLRelease(f.left, 0, f.b - 1, f.right)])
                out = _junction(STLAnd, [rec(f.right), later])
        else:
            raise InvalidTypeError(f"cannot progress {type(f).__name__}: not a PrSTL formula")
        memo[key] = out
        return out

    return rec(formula)


def _next(formula: STLFormula) -> STLFormula:
    """``next formula``: holds at step ``j`` iff ``formula`` holds at step ``j + 1``.

    Intervals of the outermost temporal operators move by one step (``f1 U[a,b] f2`` becomes
    ``f1 U[a+1,b+1] f2``, exact because ``f1`` is needed only from ``k + a`` on); an atomic
    proposition ``p`` (a constant included: under the strong reading ``TRUE`` at ``j + 1``
    needs that step to exist) becomes ``F[1,1] p``. :func:`progress` never passes a top-level
    constant: a constant there is the prefix's verdict, not an obligation.
    """
    if isinstance(formula, STLAnd | STLOr):
        return type(formula)([_next(c) for c in formula.children])
    if isinstance(formula, STLUntil):
        return STLUntil(formula.left, formula.a + 1, formula.b + 1, formula.right)
    if isinstance(formula, STLRelease):
        return STLRelease(formula.left, formula.a + 1, formula.b + 1, formula.right)
    if isinstance(formula, STLAtomicProposition):
        return STLUntil(TRUE, 1, 1, formula)
    raise InvalidTypeError(f"cannot shift {type(formula).__name__}: not a PrSTL formula")


def progress(formula: STLFormula, trajectory_prefix: ProbabilisticTSTrajectory) -> STLFormula:
    """The obligation left on the suffix once the prefix ``X_0 .. X_k`` has happened.

    Parameters
    ----------
    formula : STLFormula
        The formula the whole trajectory must satisfy (at step 0).
    trajectory_prefix : ProbabilisticTSTrajectory
        The observed prefix ``xi[:k+1]``: means (k+1, n), covariances (k+1, n, n), modes (k,).
        It includes the split step ``X_k``, which is also step 0 of the suffix.

    Returns
    -------
    STLFormula
        ``psi`` such that, for every trajectory ``xi`` beginning with the prefix,
        ``satisfies(xi, formula) == satisfies(xi[k:], psi)``; :data:`TRUE` / :data:`FALSE`
        when the prefix alone decides. ``psi`` looks only at suffix steps ``>= 1`` (everything
        at ``X_k``, including the mode used to arrive there, is decided from the prefix).

    Raises
    ------
    InvalidTypeError
        When ``formula`` is not a formula or ``trajectory_prefix`` not a belief trajectory.
    DimensionError
        When a proposition is over a variable of another dimension than the trajectory.
    """
    if not isinstance(formula, STLFormula):
        raise InvalidTypeError(f"formula must be an STLFormula, got {type(formula).__name__}")
    if not isinstance(trajectory_prefix, ProbabilisticTSTrajectory):
        raise InvalidTypeError(
            f"trajectory_prefix must be a ProbabilisticTSTrajectory, got {type(trajectory_prefix).__name__}"
        )
    means, covs = trajectory_prefix.get_mean(), trajectory_prefix.get_cov()
    actions = np.asarray(trajectory_prefix.get_action(), dtype=int)
    # Every proposition's truth at every prefix step at once (vectorised monitor).
    holds = {id(ap): atom_margins(ap, means, covs, actions) >= 0.0 for ap in formula.atomic_propositions()}
    psi = formula
    for j in range(means.shape[0]):
        psi = progress_step(psi, {key: bool(v[j]) for key, v in holds.items()})
        if psi is TRUE or psi is FALSE:
            return psi
    return _next(psi)
