"""Certificates of ``infeasible`` and their checker: exact arithmetic, a second SAT solver.

An ``infeasible`` answer of the lazy loop rests on two back ends: an LP solver (HiGHS) that
refuted requirement sets and proved LP pruning's facts, and a SAT solver that found no discrete
plan over the proven clauses. A certificate (:data:`CERTIFICATE_SCHEMA`, a plain JSON-able
dict saved with the result) lets both be re-checked without trusting either:

- ``cnf``: the SAT encoding of the formula (``encoding`` clauses, from the project's encoder)
  together with the *derived* clauses (LP pruning facts and the teachers' refutations), each
  derived clause pointing to the justification that proves it;
- ``justifications`` (or, when large, ``justifications_z``: the same list packed by
  :func:`pack_json`): per derived clause, one of

  - ``farkas``: the rows of an LP (``a_r' x <= b_r`` or ``= b_r``, the float data exactly as
    the back end was given them) and a ray ``y`` in exact rationals. :func:`check_farkas`
    re-checks ``y_r >= 0`` on inequalities, ``sum_r y_r a_r = 0`` and ``sum_r y_r b_r < 0``
    exactly (:class:`fractions.Fraction`): then no ``x`` meets the rows (Farkas' lemma);
  - ``face_violated``: a face ``h' x + c + z sqrt(h' S h) <= 0`` of a chance constraint that a
    given belief ``N(mean, S)`` violates, re-checked exactly (the square root compared by
    squares);
  - ``uncertified``: a step that has no checkable certificate yet (the reason says which); a
    certificate holding one is reported as not certified.

- the checker (:func:`check_certificate`) verifies every justification a derived clause uses,
  then asks a SAT solver of another family than the one that searched (:func:`second_solver`:
  MiniSat for CaDiCaL, CaDiCaL otherwise) whether the CNF is unsatisfiable.

What the certificate does not re-derive: that the encoding clauses encode the formula and that
an LP's rows are the ones its derived clause speaks of (both are built by the project's code,
the trusted base, as a VIPR certificate trusts its model file). The LP data themselves (the
covariance schedule in the face offsets, the dynamics) are taken as given floats.

This module imports nothing from the solve loop: only NumPy, :mod:`fractions` and python-sat.
"""

from __future__ import annotations

import base64
import heapq
import json
import math
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numpy as np

__all__ = [
    "CERTIFICATE_SCHEMA",
    "CertificateCheck",
    "check_certificate",
    "check_all_of",
    "check_face_violated",
    "check_farkas",
    "decode_clauses",
    "encode_clauses",
    "exact_ray",
    "farkas_justification",
    "pack_json",
    "second_solver",
    "unpack_json",
]

CERTIFICATE_SCHEMA = "idstlpy.certificate/1"
"""Identifier and version of a certificate's JSON form."""

_MINISAT = "minisat22"
_CADICAL = "cadical195"


def second_solver(primary: str) -> str:
    """A python-sat solver of another family than ``primary`` (the one that searched).

    Parameters
    ----------
    primary : str
        The search's python-sat solver name (``SolverOptions.sat_backend``).

    Returns
    -------
    str
        ``"minisat22"`` (MiniSat) when ``primary`` is a CaDiCaL, else ``"cadical195"``.
    """
    return _MINISAT if primary.lower().startswith("cadical") else _CADICAL


# -- clauses ------------------------------------------------------------------------------------
def encode_clauses(clauses: Sequence[Sequence[int]]) -> str:
    """Clauses as text: zero-terminated int32 literals, zlib-compressed, base64 (ASCII).

    Parameters
    ----------
    clauses : sequence of sequence of int
        DIMACS literals (non-zero).

    Returns
    -------
    str
    """
    flat: list[int] = []
    for clause in clauses:
        flat.extend(int(v) for v in clause)
        flat.append(0)
    raw = np.asarray(flat, dtype="<i4").tobytes()
    return base64.b64encode(zlib.compress(raw, 6)).decode("ascii")


def decode_clauses(text: str) -> list[list[int]]:
    """Inverse of :func:`encode_clauses`.

    Parameters
    ----------
    text : str

    Returns
    -------
    list of list of int

    Raises
    ------
    ValueError
        When ``text`` is not such an encoding.
    """
    try:
        raw = zlib.decompress(base64.b64decode(text.encode("ascii"), validate=True))
    except (ValueError, zlib.error) as exc:
        raise ValueError(f"the clauses are not a valid encoding: {exc}") from None
    if len(raw) % 4:
        raise ValueError("the clauses are not a valid encoding: not a whole number of int32")
    flat = np.frombuffer(raw, dtype="<i4")
    ends = np.flatnonzero(flat == 0)
    if flat.size and (not ends.size or ends[-1] != flat.size - 1):
        raise ValueError("the clauses are not a valid encoding: the last one has no terminating 0")
    values = flat.tolist()
    starts = np.concatenate([[0], ends[:-1] + 1]).tolist() if ends.size else []
    return [values[a:b] for a, b in zip(starts, ends.tolist(), strict=True)]


def pack_json(value: Any) -> str:
    """JSON data as text: compact JSON, zlib-compressed, base64 (a large certificate's
    justifications: a plan LP's rows repeat step after step and compress some 30-fold).

    Parameters
    ----------
    value : JSON-able data

    Returns
    -------
    str
    """
    raw = json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
    return base64.b64encode(zlib.compress(raw, 6)).decode("ascii")


def unpack_json(text: str) -> Any:
    """Inverse of :func:`pack_json`.

    Parameters
    ----------
    text : str

    Returns
    -------
    JSON data

    Raises
    ------
    ValueError
        When ``text`` is not such an encoding.
    """
    try:
        return json.loads(zlib.decompress(base64.b64decode(text.encode("ascii"), validate=True)))
    except (ValueError, zlib.error) as exc:
        raise ValueError(f"the packed justifications are not valid: {exc}") from None


# -- exact numbers ------------------------------------------------------------------------------
def _fraction(value: Any) -> Fraction:
    """An exact rational from a JSON number or a ``"p/q"`` string; finite only."""
    if isinstance(value, bool):
        raise ValueError(f"not a number: {value!r}")
    if isinstance(value, int):
        return Fraction(value)
    if isinstance(value, float):
        if not np.isfinite(value):
            raise ValueError(f"not a finite number: {value!r}")
        return Fraction(value)
    if isinstance(value, str):
        return Fraction(value)
    raise ValueError(f"not a number: {value!r}")


class _Exact:
    """Float to :class:`~fractions.Fraction`, each distinct value converted once (an LP's
    entries repeat: the dynamics are the same at every step)."""

    def __init__(self) -> None:
        self.memo: dict[float, Fraction] = {}

    def __call__(self, value: float) -> Fraction:
        got = self.memo.get(value)
        if got is None:
            got = self.memo[value] = Fraction(value)
        return got


def _text(q: Fraction) -> str:
    return str(q.numerator) if q.denominator == 1 else f"{q.numerator}/{q.denominator}"


# -- Farkas certificates --------------------------------------------------------------------------
def farkas_justification(
    indptr: Sequence[int],
    indices: Sequence[int],
    data: Sequence[float],
    rhs: Sequence[float],
    equality: Sequence[bool],
    ray: Sequence[Fraction],
    about: str,
) -> dict[str, Any]:
    """The JSON form of a Farkas certificate (rows in CSR form, the ray exact).

    Parameters
    ----------
    indptr, indices, data : sequences
        The rows ``a_r`` (CSR: row ``r`` has ``data[indptr[r]:indptr[r+1]]`` at columns
        ``indices[...]``), floats as given to the LP back end.
    rhs : sequence of float, shape (R,)
        ``b_r``.
    equality : sequence of bool, shape (R,)
        True for ``a_r' x = b_r``, False for ``a_r' x <= b_r``.
    ray : sequence of Fraction, shape (R,)
        The exact multipliers.
    about : str
        What the LP is (for messages).

    Returns
    -------
    dict
    """
    return {
        "kind": "farkas",
        "about": about,
        "indptr": [int(v) for v in indptr],
        "indices": [int(v) for v in indices],
        "data": [float(v) for v in data],
        "rhs": [float(v) for v in rhs],
        "sense": "".join("E" if e else "L" for e in equality),
        "ray": [_text(q) for q in ray],
    }


def _ratio(value: Any) -> tuple[int, int]:
    """``(numerator, denominator)`` of a JSON number or a ``"p/q"`` string, exactly."""
    if isinstance(value, float) and np.isfinite(value):
        return value.as_integer_ratio()
    q = _fraction(value)
    return q.numerator, q.denominator


def check_farkas(cert: Mapping[str, Any]) -> str | None:
    """Re-check a Farkas certificate exactly (see the module docstring).

    The sums are formed in integers: the ray scaled by the least common multiple of its
    denominators, the data (floats: dyadic rationals) by the largest power of two among theirs,
    so that no step rounds and none needs a :class:`~fractions.Fraction` per operation.

    Parameters
    ----------
    cert : mapping
        A ``farkas`` justification (:func:`farkas_justification`).

    Returns
    -------
    str or None
        ``None`` when it proves its rows infeasible, else what fails.
    """
    try:
        indptr = [int(v) for v in cert["indptr"]]
        indices = [int(v) for v in cert["indices"]]
        data = [_ratio(v) for v in cert["data"]]
        rhs = [_ratio(v) for v in cert["rhs"]]
        sense = str(cert["sense"])
        ray = [_ratio(v) for v in cert["ray"]]
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
        return f"malformed Farkas certificate: {exc}"
    R = len(rhs)
    if not (len(indptr) == R + 1 and len(sense) == R and len(ray) == R and len(indices) == len(data)):
        return "malformed Farkas certificate: the rows, senses and ray differ in length"
    if (
        indptr[0] != 0
        or indptr[-1] != len(data)
        or any(a > b for a, b in zip(indptr, indptr[1:], strict=False))
    ):
        return "malformed Farkas certificate: the row pointers are not increasing"
    if any(d <= 0 for _, d in ray):
        return "malformed Farkas certificate: a multiplier has a non-positive denominator"
    common = math.lcm(*(d for _, d in ray)) if ray else 1
    Y = [p * (common // d) for p, d in ray]  # the ray times `common`: integers, same signs
    # Every float is a dyadic rational: scale by the largest denominator (a power of two).
    D = max([d for _, d in data] + [d for _, d in rhs] + [1])
    total: dict[int, int] = {}
    value = 0
    for r in range(R):
        y = Y[r]
        if sense[r] == "L":
            if y < 0:
                return f"the multiplier of inequality row {r} is negative ({float(Fraction(*ray[r])):.3g})"
        elif sense[r] != "E":
            return f"row {r} has an unknown sense {sense[r]!r}"
        if y == 0:
            continue
        for p in range(indptr[r], indptr[r + 1]):
            num, den = data[p]
            col = indices[p]
            total[col] = total.get(col, 0) + y * num * (D // den)
        num, den = rhs[r]
        value += y * num * (D // den)
    bad = [c for c, v in total.items() if v != 0]
    if bad:
        c = min(bad)
        residual = float(Fraction(total[c], common * D))
        return f"y'A is not zero: column {c} sums to {residual:.3g} ({len(bad)} columns)"
    if value >= 0:
        return f"y'b = {float(Fraction(value, common * D)):.3g} is not negative"
    return None


def exact_ray(
    A: Any,
    rhs: np.ndarray,
    equality: np.ndarray,
    y: np.ndarray,
    pivots: np.ndarray | None = None,
    rounds: int = 4,
) -> list[Fraction] | None:
    """An exact Farkas ray near a floating-point one, or ``None``.

    The float ray ``y`` of an LP solver meets ``y'A = 0`` only to rounding. Its multipliers on
    the rows not allowed as pivots (``pivots`` False: the rows the ray is about, e.g. the
    requirements' faces) are kept as the rationals they are (negative ones clipped to 0);
    those of the pivot rows (the equalities, and inequalities that may absorb the residual) are
    solved for exactly so that ``y'A = 0`` holds, by sparse elimination in
    :class:`~fractions.Fraction` (fewest unknowns first, so block-triangular rows such as a
    plan LP's dynamics eliminate without fill). A pivot inequality that comes out negative is
    fixed at zero and the solve repeated (at most ``rounds`` times).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (R, C)
    rhs : ndarray, shape (R,)
    equality : ndarray of bool, shape (R,)
    y : ndarray, shape (R,)
        The float ray (``y >= 0`` on inequalities up to rounding, ``y'b < 0``).
    pivots : ndarray of bool, shape (R,), optional
        Rows whose multipliers may be solved for (default: every row but the one with the
        largest multiplier, which sets the ray's scale).
    rounds : int

    Returns
    -------
    list of Fraction or None
        The exact ray (``check_farkas`` of it passes), or ``None`` when none was found.
    """
    A = A.tocsr()
    R = A.shape[0]
    y = np.asarray(y, dtype=float)
    eq = np.asarray(equality, dtype=bool)
    free = np.ones(R, dtype=bool) if pivots is None else np.asarray(pivots, dtype=bool).copy()
    if free.all() and R:
        # Every row a pivot: the homogeneous solve would return 0; the largest multiplier is
        # kept as it is (the ray's scale), the others solved for.
        free[int(np.argmax(np.abs(y)))] = False
    fixed0: dict[int, Fraction] = {}
    for r in range(R):
        if not free[r]:
            v = float(y[r])
            fixed0[r] = Fraction(max(v, 0.0) if not eq[r] else v) if np.isfinite(v) else Fraction(0)
    banned: set[int] = set()
    for _ in range(max(1, rounds)):
        out = _solve_pivots(A, eq, y, free, fixed0, banned)
        if out is None:
            return None
        ray, negative = out
        if negative:
            banned.update(negative)
            continue
        if _value(ray, rhs) < 0:
            return [ray.get(r, Fraction(0)) for r in range(R)]
        return None
    return None


def _value(ray: Mapping[int, Fraction], rhs: np.ndarray) -> Fraction:
    exact = _Exact()
    return sum((q * exact(float(rhs[r])) for r, q in ray.items() if q), Fraction(0))


def _solve_pivots(
    A: Any,
    eq: np.ndarray,
    y: np.ndarray,
    free: np.ndarray,
    fixed0: Mapping[int, Fraction],
    banned: set[int],
) -> tuple[dict[int, Fraction], list[int]] | None:
    """One exact solve of :func:`exact_ray`: the ray and the pivot inequalities that came out
    negative (``None`` when a column's equation cannot be met)."""
    R = A.shape[0]
    scale = float(np.max(np.abs(y))) if y.size else 0.0
    if not np.isfinite(scale) or scale == 0:
        return None
    fixed = dict(fixed0)
    for r in banned:
        fixed[r] = Fraction(0)
    unknown = [r for r in range(R) if free[r] and r not in banned]
    AT = A.T.tocsr()
    exact = _Exact()
    # One equation per column: sum_r A[r, c] y_r = 0, the fixed multipliers moved to the right.
    eqs: dict[int, dict[int, Fraction]] = {}
    rhs: dict[int, Fraction] = {}
    is_unknown = np.zeros(R, dtype=bool)
    is_unknown[unknown] = True
    for c in range(AT.shape[0]):
        lo, hi = AT.indptr[c], AT.indptr[c + 1]
        if lo == hi:
            continue
        row: dict[int, Fraction] = {}
        b = Fraction(0)
        for r, a in zip(AT.indices[lo:hi].tolist(), AT.data[lo:hi].tolist(), strict=True):
            if a == 0:
                continue
            if is_unknown[r]:
                row[r] = exact(a)
            else:
                q = fixed.get(r, Fraction(0))
                if q:
                    b -= exact(a) * q
        if row or b:
            eqs[c] = row
            rhs[c] = b
    where: dict[int, set[int]] = {}
    for c, row in eqs.items():
        for r in row:
            where.setdefault(r, set()).add(c)
    order: list[tuple[int, int, dict[int, Fraction], Fraction]] = []  # (pivot, column, row, b)
    live = set(eqs)
    # Fewest unknowns first (a heap with stale entries skipped: an equation is pushed again each
    # time its count changes).
    heap = [(len(row), c) for c, row in eqs.items()]
    heapq.heapify(heap)
    while live:
        count, c = heapq.heappop(heap)
        if c not in live or count != len(eqs[c]):
            continue
        row, b = eqs[c], rhs[c]
        live.discard(c)
        if not row:
            if b != 0:
                return None  # the fixed multipliers leave a residual no pivot can take
            continue
        # Prefer equalities (free sign), then the inequality the float ray leans on most.
        p = max(row, key=lambda r: (bool(eq[r]), abs(float(y[r]))))
        a = row[p]
        order.append((p, c, row, b))
        for c2 in list(where.get(p, ())):
            if c2 == c or c2 not in live:
                continue
            other = eqs[c2]
            f = other.pop(p)
            if a != 1:
                f = f / a
            for r, v in row.items():
                if r == p:
                    continue
                nv = other.get(r, Fraction(0)) - f * v
                if nv:
                    other[r] = nv
                else:
                    other.pop(r, None)
                    where[r].discard(c2)
                if nv:
                    where.setdefault(r, set()).add(c2)
            rhs[c2] -= f * b
            heapq.heappush(heap, (len(other), c2))
        where.pop(p, None)
    values: dict[int, Fraction] = {r: q for r, q in fixed.items()}
    pivoted = {p for p, _, _, _ in order}
    for r in unknown:
        if r not in pivoted:  # an unknown no equation needed: its float value, clipped
            fv = float(y[r])
            kept = fv if eq[r] else max(fv, 0.0)
            values[r] = Fraction(kept) if abs(fv) > 1e-12 * scale else Fraction(0)
    for p, _, row, b in reversed(order):
        s = b
        for r, v in row.items():
            if r != p:
                s -= v * values[r]
        a = row[p]
        values[p] = s if a == 1 else s / a
    negative = [r for r in unknown if not eq[r] and values.get(r, Fraction(0)) < 0]
    return values, negative


# -- chance-constraint faces ----------------------------------------------------------------------
def check_face_violated(cert: Mapping[str, Any]) -> str | None:
    """Re-check exactly that a belief violates a face ``h' x + c + z sqrt(h' S h) <= 0``.

    Parameters
    ----------
    cert : mapping
        ``{"kind": "face_violated", "h", "c", "z" (a number or "inf"), "mean", "cov"}``.

    Returns
    -------
    str or None
        ``None`` when ``h' mean + c + z sqrt(h' cov h) > 0`` holds exactly (with ``z = inf``:
        when ``h' cov h > 0``), else what fails.
    """
    try:
        h = [_fraction(v) for v in cert["h"]]
        c = _fraction(cert["c"])
        z_raw = cert["z"]
        z_inf = z_raw == "inf"
        z = Fraction(0) if z_inf else _fraction(z_raw)
        mean = [_fraction(v) for v in cert["mean"]]
        cov = [[_fraction(v) for v in row] for row in cert["cov"]]
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
        return f"malformed face certificate: {exc}"
    n = len(h)
    if len(mean) != n or len(cov) != n or any(len(row) != n for row in cov):
        return "malformed face certificate: the shapes of h, mean and cov differ"
    var = sum((h[i] * cov[i][j] * h[j] for i in range(n) for j in range(n)), Fraction(0))
    if z_inf:
        return None if var > 0 else "z is infinite but the variance along h is not positive"
    if z < 0:
        return "z is negative (a chance constraint with eps > 0.5)"
    a = sum((h[i] * mean[i] for i in range(n)), Fraction(0)) + c
    if var < 0:
        return "the variance along h is negative"
    if a > 0 or (z * z * var > a * a and a <= 0 and z > 0 and var > 0):
        return None
    return f"the face holds for the belief (h'mean + c = {float(a):.3g}, z^2 var = {float(z * z * var):.3g})"


# -- the whole certificate ------------------------------------------------------------------------
@dataclass
class CertificateCheck:
    """What :func:`check_certificate` found.

    Attributes
    ----------
    ok : bool
        Every part checked: the justifications the derived clauses use verify, and the second
        SAT solver finds the CNF unsatisfiable.
    certified : bool
        ``ok`` and no part is ``uncertified``.
    messages : list of str
        What failed (empty when ``ok``).
    uncertified : list of str
        The parts without a checkable certificate (their reasons).
    counts : dict
        Justifications checked per kind, and the CNF's size.
    """

    ok: bool
    certified: bool
    messages: list[str] = field(default_factory=list)
    uncertified: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)

    def summary(self) -> str:
        """One line for a user."""
        if not self.ok:
            return "certificate FAILED: " + "; ".join(self.messages[:3])
        if not self.certified:
            return "certificate checked, but not every step is certified: " + "; ".join(self.uncertified[:3])
        parts = ", ".join(f"{v} {k}" for k, v in sorted(self.counts.items()))
        return f"certificate verified ({parts})"


def check_all_of(cert: Mapping[str, Any]) -> str | None:
    """Re-check every part of an ``all_of`` justification (e.g. one LP per mode).

    Parameters
    ----------
    cert : mapping
        ``{"kind": "all_of", "parts": [justification, ...]}``.

    Returns
    -------
    str or None
        ``None`` when every part verifies, else the first failure.
    """
    parts = cert.get("parts")
    if not isinstance(parts, list) or not parts:
        return "an all_of justification without parts"
    for i, part in enumerate(parts):
        kind = part.get("kind") if isinstance(part, Mapping) else None
        check = _CHECKS.get(str(kind))
        if check is None:
            return f"part {i} has an unknown or uncertified kind {kind!r}"
        why = check(part)
        if why is not None:
            return f"part {i}: {why}"
    return None


_CHECKS: dict[str, Any] = {
    "farkas": check_farkas,
    "face_violated": check_face_violated,
    "all_of": check_all_of,
}


def check_certificate(cert: Mapping[str, Any]) -> CertificateCheck:
    """Re-check a certificate of ``infeasible`` without trusting the back ends that made it.

    Parameters
    ----------
    cert : mapping
        A certificate (:data:`CERTIFICATE_SCHEMA`), as saved in a result's ``certificate`` field.

    Returns
    -------
    CertificateCheck
    """
    if not isinstance(cert, Mapping) or cert.get("schema") != CERTIFICATE_SCHEMA:
        got = cert.get("schema") if isinstance(cert, Mapping) else type(cert).__name__
        return CertificateCheck(
            False, False, [f"not a certificate of schema {CERTIFICATE_SCHEMA!r} (got {got!r})"]
        )
    uncertified = [str(u) for u in cert.get("uncertified", [])]
    route = cert.get("route")
    if route != "sat":
        why = uncertified or [f"the proof route {route!r} has no checkable certificate"]
        return CertificateCheck(True, False, [], why, {})
    messages: list[str] = []
    counts: dict[str, int] = {}
    justs = cert.get("justifications")
    if justs is None and isinstance(cert.get("justifications_z"), str):
        try:
            justs = unpack_json(cert["justifications_z"])
        except ValueError as exc:
            return CertificateCheck(False, False, [str(exc)], uncertified)
    cnf = cert.get("cnf")
    if not isinstance(justs, list) or not isinstance(cnf, Mapping):
        return CertificateCheck(
            False, False, ["the certificate has no CNF or no justifications"], uncertified
        )
    verdicts: dict[int, str | None] = {}
    for idx, just in enumerate(justs):
        kind = just.get("kind") if isinstance(just, Mapping) else None
        if kind == "uncertified":
            verdicts[idx] = None
            uncertified.append(str(just.get("why", "a step without a certificate")))
            counts["uncertified"] = counts.get("uncertified", 0) + 1
            continue
        check = _CHECKS.get(str(kind))
        if check is None:
            verdicts[idx] = f"justification {idx} has an unknown kind {kind!r}"
            continue
        verdicts[idx] = check(just)
        counts[str(kind)] = counts.get(str(kind), 0) + 1
    try:
        encoding = decode_clauses(str(cnf["encoding"]))
        derived = decode_clauses(str(cnf["derived"]))
        by = [int(v) for v in cnf["justified_by"]]
        num_vars = int(cnf["num_vars"])
    except (KeyError, TypeError, ValueError) as exc:
        return CertificateCheck(False, False, [f"malformed CNF: {exc}"], uncertified)
    if len(by) != len(derived):
        return CertificateCheck(False, False, ["every derived clause needs one justification"], uncertified)
    for i, j in enumerate(by):
        if j not in verdicts:
            messages.append(f"derived clause {i} points to justification {j}, which does not exist")
        elif verdicts[j] is not None:
            messages.append(f"derived clause {i}: {verdicts[j]}")
    if any(abs(v) > num_vars for clause in encoding + derived for v in clause):
        messages.append("a clause uses a variable beyond num_vars")
    counts["encoding clauses"] = len(encoding)
    counts["derived clauses"] = len(derived)
    if not messages:
        solver_name = str(cert.get("second_solver", _MINISAT))
        sat = _satisfiable(solver_name, encoding + derived)
        if sat is None:
            messages.append(f"the second SAT solver {solver_name!r} cannot be used")
        elif sat:
            messages.append(f"the second SAT solver ({solver_name}) finds the CNF satisfiable")
    ok = not messages
    return CertificateCheck(ok, ok and not uncertified, messages, uncertified, counts)


def _satisfiable(name: str, clauses: list[list[int]]) -> bool | None:
    """Whether ``clauses`` are satisfiable for python-sat's solver ``name`` (``None``: no such
    solver)."""
    from pysat.solvers import NoSuchSolverError, Solver

    try:
        with Solver(name=name, bootstrap_with=clauses) as solver:
            return bool(solver.solve())
    except (NoSuchSolverError, ValueError, NotImplementedError):
        return None
