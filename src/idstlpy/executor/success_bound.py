"""Sound lower bounds on a formula's success under the predicted (Gaussian) closed loop.

Per chance constraint of every atomic proposition, the left-hand side at step ``k`` is linear in
the loop's Gaussian state (:class:`Faces`, :func:`stack_faces`); a witness of the formula (the
plan's own, or the cheapest one a dynamic programme on the failure probabilities finds) names
the events it needs, and one minus Hunter's tree bound on the union of their failures (exact
bivariate normal probabilities along each constraint's chain of steps,
:func:`bivariate_normal_cdf`) bounds the success from below (:func:`success_bound`). The
derivation is in :mod:`idstlpy.executor.predict`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ndtr, owens_t

from ..chance import std_terms
from ..closed_loop import ClosedLoopMoments, prob_le
from ..errors import DimensionError, InvalidTypeError
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil
from ..label_semantics import extract_witness

__all__ = ["Faces", "bivariate_normal_cdf", "mode_truth", "stack_faces", "success_bound"]

_INTERSECTION_SLACK = 1e-9
"""Subtracted from every bivariate probability the Hunter bound uses (numerical safety)."""


# --------------------------------------------------------------------------------------------
# Bivariate normal


def bivariate_normal_cdf(h: ArrayLike, k: ArrayLike, rho: ArrayLike) -> np.ndarray:
    """``P[Z1 <= h, Z2 <= k]`` for standard normals with correlation ``rho`` (Owen's T).

    Parameters
    ----------
    h, k : array_like, broadcastable
        Upper limits (``+-inf`` allowed).
    rho : array_like, broadcastable
        Correlations in ``[-1, 1]``.

    Returns
    -------
    ndarray
        The probabilities, clipped to the Frechet bounds ``[max(0, Phi(h) + Phi(k) - 1),
        min(Phi(h), Phi(k))]``.
    """
    h, k, rho = np.broadcast_arrays(
        np.asarray(h, dtype=float), np.asarray(k, dtype=float), np.clip(np.asarray(rho, dtype=float), -1, 1)
    )
    ph, pk = ndtr(h), ndtr(k)
    lo, hi = np.maximum(0.0, ph + pk - 1.0), np.minimum(ph, pk)
    s = np.sqrt(np.maximum(0.0, 1.0 - rho * rho))
    finite = np.isfinite(h) & np.isfinite(k)
    # Zeros are taken as +0 (the limit from above, consistent with the beta rule below).
    hf = np.where(finite & (h != 0), h, np.where(finite, 0.0, 1.0))
    kf = np.where(finite & (k != 0), k, np.where(finite, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ah = (kf - rho * hf) / (hf * s)
        ak = (hf - rho * kf) / (kf * s)
        sign = np.sign(hf) * np.sign(kf)  # not hf * kf, which underflows
        beta = np.where((sign > 0) | ((sign == 0) & (hf + kf >= 0)), 0.0, 0.5)
        general = 0.5 * (ph + pk) - owens_t(hf, ah) - owens_t(kf, ak) - beta
    origin = 0.25 + np.arcsin(rho) / (2 * np.pi)
    out = np.where((hf == 0) & (kf == 0), origin, general)
    degenerate = s < 1e-9
    out = np.where(degenerate & (rho > 0), hi, out)
    out = np.where(degenerate & (rho < 0), lo, out)
    # An infinite limit: the probability is a marginal (or 0), i.e. the Frechet bounds meet.
    out = np.where(finite, out, np.where(np.isposinf(h) | np.isposinf(k), hi, 0.0))
    out = np.where(np.isnan(out), hi, out)
    return np.clip(out, lo, hi)


def _standardised(mu: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``mu / sd`` with ``+-inf`` for ``sd == 0`` (the sign of ``mu``; ``mu <= 0`` gives ``-inf``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = mu / sd
    return np.where(sd > 0, t, np.where(mu > 0, np.inf, -np.inf))


@dataclass
class Faces:
    """The chance constraints of the formula's propositions, stacked (``F`` faces).

    For each reading (``"state"``, ``"belief"``) the constraint's left-hand side at step ``k`` is
    ``a[k, f] . z_k + const[k, f]`` (the constraint holds when it is ``<= 0``).
    """

    H: np.ndarray  # (F, n)
    c: np.ndarray  # (F,)
    z: np.ndarray  # (F,)
    atom: np.ndarray  # (F,) index of the proposition
    a: dict[str, np.ndarray]  # (L, F, D)
    mu: dict[str, np.ndarray]  # (L, F) mean of the left-hand side
    sd: dict[str, np.ndarray]  # (L, F) its standard deviation


def stack_faces(
    aps: list[STLAtomicProposition], loop: ClosedLoopMoments, plan_means: np.ndarray, n: int
) -> Faces:
    rows_H, rows_c, rows_z, rows_a = [], [], [], []
    for i, ap in enumerate(aps):
        cone = ap.cone
        if cone.num_faces == 0:
            continue
        if cone.dim != n:
            raise DimensionError(
                f"proposition {ap.name or ap} is over a {cone.dim}-dimensional variable, "
                f"the state has n = {n}"
            )
        rows_H.append(cone.H)
        rows_c.append(cone.c)
        rows_z.append(cone.z)
        rows_a.append(np.full(cone.num_faces, i))
    if rows_H:
        H, c = np.vstack(rows_H), np.concatenate(rows_c)
        z, atom = np.concatenate(rows_z), np.concatenate(rows_a).astype(int)
    else:
        H, c, z, atom = np.zeros((0, n)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    L, D = loop.mean.shape
    nF = H.shape[0]
    a_x = np.zeros((L, nF, D))
    a_x[:, :, :n] = H[None]
    a_b = np.zeros((L, nF, D))
    a_b[:, :, n : 2 * n] = H[None]
    terms = std_terms(H, z, loop.P)  # (L, F): z sqrt(h' P h) at the linearisation point
    if loop.sensitivity and nF:
        # d sqrt(h' P h) = h' dP h / (2 sqrt(h' P h)); no first-order term where it is 0 or eps = 0.
        sd_bar = np.sqrt(np.maximum(np.einsum("fi,kij,fj->kf", H, loop.P, H), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.where((sd_bar > 0) & np.isfinite(z)[None], z[None] / (2 * sd_bar), 0.0)
        hh = np.einsum("fi,fj->fij", H, H).reshape(nF, n * n)
        a_b[:, :, 2 * n :] = coef[:, :, None] * hh[None]
    const_x = plan_means @ H.T + c
    const_b = const_x + terms
    mu, sd = {}, {}
    for name, a, const in (("state", a_x, const_x), ("belief", a_b, const_b)):
        mu[name] = np.einsum("kfd,kd->kf", a, loop.mean) + const
        sd[name] = np.sqrt(np.maximum(np.einsum("kfd,kde,kfe->kf", a, loop.cov, a), 0.0))
    return Faces(H, c, z, atom, {"state": a_x, "belief": a_b}, mu, sd)


def mode_truth(aps: list[STLAtomicProposition], actions: np.ndarray, L: int) -> np.ndarray:
    """``ok[a, k]``: the mode part of proposition ``a`` holds at step ``k`` (plan modes), (A, L)."""
    ok = np.ones((len(aps), L), dtype=bool)
    for i, ap in enumerate(aps):
        if ap.is_false:
            ok[i] = False
        elif ap.modes is not None and L > 1:
            ok[i, 1:] = np.isin(actions[: L - 1], np.fromiter(ap.modes, dtype=int, count=len(ap.modes)))
    return ok


def _shift(arr: np.ndarray, d: int) -> np.ndarray:
    """``arr[k + d]`` for every ``k`` (``+inf`` cost past the end)."""
    L = arr.shape[0]
    out = np.full(L, np.inf)
    if d < L:
        out[: L - d] = arr[d:]
    return out


def _dp_costs(formula: STLFormula, atom_cost: dict[int, np.ndarray], L: int) -> dict[int, np.ndarray]:
    """Additive union-bound cost of the cheapest witness of every sub-formula at every step.

    ``atom_cost[id(ap)]`` (L,) is the summed violation probability of the proposition's faces
    (``inf`` where it cannot hold). And sums, or takes the minimum, until / release take the
    cheapest witness step. Costs are sound upper bounds on the failure probability.
    """
    memo: dict[int, np.ndarray] = {}

    def rec(f: STLFormula) -> np.ndarray:
        key = id(f)
        if key in memo:
            return memo[key]
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = np.full(L, np.inf)
            elif key in atom_cost:
                out = atom_cost[key]
            else:
                out = np.zeros(L)
        elif isinstance(f, STLAnd):
            out = np.sum([rec(c) for c in f.children], axis=0)
        elif isinstance(f, STLOr):
            out = np.minimum.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLUntil):
            c1, c2 = rec(f.left), rec(f.right)
            out = np.full(L, np.inf)
            prefix = np.zeros(L)
            for d in range(f.a, min(f.b, L - 1) + 1):
                out = np.minimum(out, _shift(c2, d) + prefix)
                prefix = prefix + _shift(c1, d)
        elif isinstance(f, STLRelease):
            c1, c2 = rec(f.left), rec(f.right)
            out = np.full(L, np.inf)
            prefix = np.zeros(L)
            for d in range(f.a, f.b + 1):
                prefix = prefix + _shift(c2, d)
                out = np.minimum(out, _shift(c1, d) + prefix)
                if d >= L:
                    break
            out = np.minimum(out, prefix)
        else:
            raise InvalidTypeError(f"cannot bound {type(f).__name__}")
        memo[key] = out
        return out

    rec(formula)
    return memo


def _dp_witness(
    formula: STLFormula, costs: dict[int, np.ndarray], atom_index: dict[int, int], L: int
) -> set[tuple[int, int]] | None:
    """The (atom, step) pairs of the cheapest witness the costs describe (None when impossible)."""
    if not np.isfinite(costs[id(formula)][0]):
        return None
    need: set[tuple[int, int]] = set()
    seen: set[tuple[int, int]] = set()
    stack: list[tuple[STLFormula, int]] = [(formula, 0)]

    def cost(f: STLFormula, j: int) -> float:
        return float(costs[id(f)][j]) if 0 <= j < L else np.inf

    while stack:
        f, k = stack.pop()
        if (id(f), k) in seen:
            continue
        seen.add((id(f), k))
        if isinstance(f, STLAtomicProposition):
            if id(f) in atom_index:
                need.add((atom_index[id(f)], k))
        elif isinstance(f, STLAnd):
            stack.extend((c, k) for c in f.children)
        elif isinstance(f, STLOr):
            stack.append((min(f.children, key=lambda c: cost(c, k)), k))
        elif isinstance(f, STLUntil):
            best, best_j, prefix = np.inf, -1, 0.0
            for j in range(k + f.a, min(k + f.b, L - 1) + 1):
                total = cost(f.right, j) + prefix
                if total < best:
                    best, best_j = total, j
                prefix += cost(f.left, j)
            stack.append((f.right, best_j))
            stack.extend((f.left, j) for j in range(k + f.a, best_j))
        elif isinstance(f, STLRelease):
            best, best_j, prefix = np.inf, None, 0.0
            for j in range(k + f.a, k + f.b + 1):
                prefix += cost(f.right, j)
                total = cost(f.left, j) + prefix
                if total < best:
                    best, best_j = total, j
                if j >= L:
                    break
            if prefix <= best:  # the right side on the whole window
                best_j = None
            end = k + f.b if best_j is None else best_j
            if best_j is not None:
                stack.append((f.left, best_j))
            stack.extend((f.right, j) for j in range(k + f.a, end + 1))
    return need


def _hunter_failure(
    events: list[tuple[int, int]], faces: Faces, reading: str, loop: ClosedLoopMoments
) -> float:
    """Hunter's bound ``sum P(A_i) - sum_{tree} P(A_i & A_j)`` on ``P(some event fails)``.

    ``events`` are (face, step) pairs; faces with the same constraint (``h, c`` and, for the
    belief, ``eps``) are merged; the tree chains each constraint's steps in time order.
    """
    mu, sd, a = faces.mu[reading], faces.sd[reading], faces.a[reading]
    groups: dict[tuple[Any, ...], set[int]] = {}
    rep: dict[tuple[Any, ...], int] = {}
    for f, k in events:
        key: tuple[Any, ...] = (*faces.H[f].tolist(), float(faces.c[f]))
        if reading == "belief":
            key = (*key, float(faces.z[f]))
        groups.setdefault(key, set()).add(k)
        rep.setdefault(key, f)
    total = 0.0
    for key, steps in groups.items():
        f = rep[key]
        ks = sorted(steps)
        p = 1.0 - prob_le(mu[ks, f], sd[ks, f])
        total += float(np.sum(p))
        if len(ks) < 2:
            continue
        # Chain edges: Cov(a_k' z_k, a_j' z_j) = a_k' F_{k-1} ... F_j Cov(z_j) a_j.
        t = _standardised(mu[ks, f], sd[ks, f])
        rhos = np.zeros(len(ks) - 1)
        for i in range(len(ks) - 1):
            j, k = ks[i], ks[i + 1]
            vec = loop.cov[j] @ a[j, f]
            for s in range(j, k):
                vec = loop.F[s] @ vec
            denom = sd[j, f] * sd[k, f]
            if denom > 0:
                rhos[i] = float(a[k, f] @ vec) / denom
        both = bivariate_normal_cdf(t[:-1], t[1:], rhos)
        both = np.maximum(0.0, np.minimum(both - _INTERSECTION_SLACK, np.minimum(p[:-1], p[1:])))
        total -= float(np.sum(both))
    return max(0.0, min(1.0, total))


def success_bound(
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    faces: Faces,
    mode_ok: np.ndarray,
    plan_truth: np.ndarray,
    reading: str,
    loop: ClosedLoopMoments,
) -> tuple[float, list[tuple[int, int]]]:
    """Lower bound on the formula's success for one reading, and the witness used."""
    L = mode_ok.shape[1]
    atom_index = {id(ap): i for i, ap in enumerate(aps)}
    viol = 1.0 - prob_le(faces.mu[reading], faces.sd[reading])  # (L, F)
    atom_cost: dict[int, np.ndarray] = {}
    for i, ap in enumerate(aps):
        cost = viol[:, faces.atom == i].sum(axis=1)
        atom_cost[id(ap)] = np.where(mode_ok[i], cost, np.inf)
    candidates: list[set[tuple[int, int]]] = []
    dp = _dp_witness(formula, _dp_costs(formula, atom_cost, L), atom_index, L)
    if dp is not None:
        candidates.append(dp)
    for late in (True, False):
        got = extract_witness(formula, plan_truth, atom_index, prefer_late=late)
        if got is not None:
            candidates.append({(int(i), int(k)) for i, k in zip(*np.nonzero(got[0]), strict=True)})
    best, best_w = np.inf, []
    for w in candidates:
        if any(not mode_ok[i, k] for i, k in w):
            continue
        events = [(int(f), k) for i, k in w for f in np.flatnonzero(faces.atom == i)]
        fail = _hunter_failure(events, faces, reading, loop) if events else 0.0
        if fail < best:
            best, best_w = fail, sorted(w, key=lambda t: (t[1], t[0]))
    if not np.isfinite(best):
        return 0.0, []
    return 1.0 - best, best_w
