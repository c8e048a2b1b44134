"""PrSTL's Boolean semantics on a label trace, and the witness a satisfying trace contains.

A *label trace* says which atomic propositions hold at every step (``truth[i, k]``: atom ``i`` at
step ``k``), as a SAT model of the discrete abstraction or a sampled execution does.
:func:`evaluate_bool` gives the truth of every sub-formula at every step (the strong finite-trace
reading of :mod:`idstlpy.semantics`, on labels instead of beliefs). Because PrSTL has no negation,
a formula only needs a *witness*: a set of (proposition, step) pairs whose truth implies it;
:func:`extract_witness` picks one by walking the formula top down (one true disjunct, one
until-witness step).

A model-layer module: the planner (:mod:`idstlpy.synthesis.plan`) turns witnesses into discrete
plans, and the executor (:mod:`idstlpy.executor.model_sampling`,
:mod:`idstlpy.executor.success_bound`) evaluates sampled traces with it.
"""

from __future__ import annotations

import numpy as np

from .formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil

__all__ = ["evaluate_bool", "extract_witness"]


def _next_true(v: np.ndarray) -> np.ndarray:
    """``out[j]`` = first index ``i >= j`` with ``v[i]`` (``L`` if none), for ``j`` in ``0..L``."""
    L = v.shape[0]
    idx = np.where(v, np.arange(L), L)
    out = np.empty(L + 1, dtype=np.int64)
    out[L] = L
    out[:L] = np.minimum.accumulate(idx[::-1])[::-1]
    return out


def _prev_true(v: np.ndarray) -> np.ndarray:
    """``out[j]`` = last index ``i <= j`` with ``v[i]`` (``-1`` if none), for ``j`` in ``0..L-1``."""
    L = v.shape[0]
    idx = np.where(v, np.arange(L), -1)
    return np.maximum.accumulate(idx) if L else np.zeros(0, dtype=np.int64)


def _is_constant_true(f: STLFormula, atom_index: dict[int, int]) -> bool:
    return isinstance(f, STLAtomicProposition) and f.is_true and id(f) not in atom_index


def evaluate_bool(
    formula: STLFormula, truth: np.ndarray, atom_index: dict[int, int]
) -> dict[int, np.ndarray]:
    """Truth of every sub-formula at every step of a label trace, in ``O(L)`` per operator.

    Interval operators use "next index" arrays instead of scanning windows: ``f1 U[a,b] f2``
    holds at ``k`` iff the first ``f2`` from ``k+a`` comes no later than ``k+b`` and no later
    than the first failure of ``f1`` from ``k+a``.

    Parameters
    ----------
    truth : ndarray of bool, shape (n_atoms, L)
    atom_index : dict
        ``id(atom) -> row of truth``.

    Returns
    -------
    dict
        ``id(subformula) -> bool array (L,)``.
    """
    L = truth.shape[1]
    ks = np.arange(L)
    memo: dict[int, np.ndarray] = {}

    def rec(f: STLFormula) -> np.ndarray:
        got = memo.get(id(f))
        if got is not None:
            return got
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = np.zeros(L, dtype=bool)
            elif id(f) in atom_index:
                out = truth[atom_index[id(f)]].astype(bool)
            else:
                out = np.ones(L, dtype=bool)
        elif isinstance(f, STLAnd):
            out = np.logical_and.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLOr):
            out = np.logical_or.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLUntil | STLRelease):
            v1, v2 = rec(f.left), rec(f.right)
            j0 = np.minimum(ks + f.a, L)
            last = ks + f.b
            if isinstance(f, STLUntil):
                hit = _next_true(v2)[j0]
                out = (hit < L) & (hit <= last) & (hit <= _next_true(~v1)[j0])
            else:
                fail2 = _next_true(~v2)[j0]
                both = _next_true(v1 & v2)[j0]
                out = ((last < L) & (fail2 > last)) | ((both < L) & (both <= last) & (both < fail2))
        else:
            raise TypeError(f"cannot evaluate {type(f).__name__}")
        memo[id(f)] = out
        return out

    rec(formula)
    return memo


def extract_witness(
    formula: STLFormula,
    truth: np.ndarray,
    atom_index: dict[int, int],
    prefer_late: bool = True,
) -> tuple[np.ndarray, int] | None:
    """A sufficient set of requirements for ``formula`` at step 0 on the label trace ``truth``.

    Parameters
    ----------
    prefer_late : bool
        Pick the latest until-witness step (leaves the teacher the most time to get there)
        instead of the earliest.

    Returns
    -------
    (required, length) or None
        ``required`` has the shape of ``truth``; ``length`` is one past the last step the
        witness touches. ``None`` when the trace does not satisfy the formula.
    """
    values = evaluate_bool(formula, truth, atom_index)
    if not values[id(formula)][0]:
        return None
    L = truth.shape[1]
    # The witness is the closure of (formula, 0) under "this sub-formula must hold at this step",
    # each choice depending on the pair alone: it is built sub-formula by sub-formula, parents
    # first, over the set of steps each must hold at (one vectorised pass per sub-formula).
    order = _parents_first(formula)
    need: dict[int, np.ndarray] = {id(f): np.zeros(L, dtype=bool) for f in order}
    need[id(formula)][0] = True
    required = np.zeros_like(truth, dtype=bool)
    last = 0
    for f in order:
        mask = need[id(f)]
        if not mask.any():
            continue
        ks = np.flatnonzero(mask)
        last = max(last, int(ks[-1]))
        if isinstance(f, STLAtomicProposition):
            if id(f) in atom_index:
                required[atom_index[id(f)], ks] = True
        elif isinstance(f, STLAnd):
            for c in f.children:
                need[id(c)] |= mask
        elif isinstance(f, STLOr):
            left = mask.copy()  # each step to the first child true there
            for c in f.children:
                hit = left & values[id(c)]
                need[id(c)] |= hit
                left &= ~hit
        elif isinstance(f, STLUntil):
            last = max(last, _until_witness(f, ks, values, need, atom_index, prefer_late))
        elif isinstance(f, STLRelease):
            last = max(last, _release_witness(f, ks, values, need, atom_index))
        else:
            raise TypeError(f"cannot justify {type(f).__name__}")
    return required, last + 1


def _until_witness(
    f: STLUntil,
    ks: np.ndarray,
    values: dict[int, np.ndarray],
    need: dict[int, np.ndarray],
    atom_index: dict[int, int],
    prefer_late: bool,
) -> int:
    """Mark in ``need`` what ``f`` holding at steps ``ks`` requires; return the last step it touches."""
    L = need[id(f)].shape[0]
    v1, v2 = values[id(f.left)], values[id(f.right)]
    first = np.minimum(ks + f.a, L)
    end = np.minimum(ks + f.b, L - 1)
    # Witnesses: j in [start, min(end, first failure of the left side)] with the right side.
    limit = np.minimum(end, _next_true(~v1)[first])
    if prefer_late:
        prev = _prev_true(v2)
        chosen = np.where(first <= limit, prev[np.clip(limit, 0, L - 1)], -1)
    else:
        chosen = _next_true(v2)[first]
        chosen = np.where(chosen <= limit, chosen, -1)
    if np.any(chosen < first):  # the evaluation said true: unreachable
        raise RuntimeError("until witness not found on a satisfying trace")
    need[id(f.right)][chosen] = True
    if not _is_constant_true(f.left, atom_index):
        need[id(f.left)] |= _cover(first, chosen, L)
    return int(chosen.max())


def _release_witness(
    f: STLRelease,
    ks: np.ndarray,
    values: dict[int, np.ndarray],
    need: dict[int, np.ndarray],
    atom_index: dict[int, int],
) -> int:
    """Mark in ``need`` what ``f`` holding at steps ``ks`` requires; return the last step it touches."""
    L = need[id(f)].shape[0]
    v1, v2 = values[id(f.left)], values[id(f.right)]
    first = ks + f.a
    stop = ks + f.b
    s0 = np.minimum(first, L)
    fail2 = _next_true(~v2)[s0]
    both = _next_true(v1 & v2)[s0]
    hit = (both < fail2) & (both <= np.minimum(stop, L - 1))
    end = np.where(hit, both, stop)
    need[id(f.left)][both[hit]] = True
    if not _is_constant_true(f.right, atom_index):
        need[id(f.right)] |= _cover(first, end + 1, L)
    return int(end.max())


def _parents_first(formula: STLFormula) -> list[STLFormula]:
    """The distinct sub-formulas of ``formula`` (by identity), every one after all its parents."""
    post: list[STLFormula] = []
    seen: set[int] = set()
    stack: list[tuple[STLFormula, bool]] = [(formula, False)]
    while stack:
        f, done = stack.pop()
        if done:
            post.append(f)
            continue
        if id(f) in seen:
            continue
        seen.add(id(f))
        stack.append((f, True))
        if isinstance(f, STLAnd | STLOr):
            stack.extend((c, False) for c in reversed(f.children))
        elif isinstance(f, STLUntil | STLRelease):
            stack.extend([(f.right, False), (f.left, False)])
    return post[::-1]


def _cover(lo: np.ndarray, hi: np.ndarray, L: int) -> np.ndarray:
    """The union of the step ranges ``[lo[r], hi[r])``, clipped to ``0..L-1``, as a mask (L,)."""
    lo, hi = np.clip(lo, 0, L), np.clip(hi, 0, L)
    keep = hi > lo
    edges = np.zeros(L + 1, dtype=np.int64)
    np.add.at(edges, lo[keep], 1)
    np.add.at(edges, hi[keep], -1)
    return np.cumsum(edges[:L]) > 0
