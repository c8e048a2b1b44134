"""Problems feasible or infeasible *by construction*: the ground truth of issue 10's soundness tests.

Every problem is built with the public API only (``import idstlpy as stl``); what makes it feasible
or infeasible is decided here, independently of the solver:

Feasible (:func:`feasible_instance`)
    Random small dynamics (integrators, double integrators, random stable or marginal ``A``;
    one or two modes; optional process noise; no sensor, a sensor with constant noise, or a
    sensor whose noise is a Python function of the state), a random control domain (a box, a
    domain unbounded on some sides, or a flat one: an input pinned to 0 next to free ones), a
    point or Gaussian prior, and a random admissible roll-out (modes and controls inside the
    domain, 2-12 steps) computed with the independent roll-out of :mod:`oracles.rollout`. A random
    nested formula is then built *around* that roll-out: each chance constraint's offset is set
    so that it holds on the steps the formula needs with a random slack ``>= 0`` (exactly zero
    now and then), operators and intervals are chosen so that the roll-out witnesses them. The
    witness is checked with the brute-force monitor (:mod:`oracles.brute_force`) before the
    instance is returned. Every length (states, bounds, noise, prior) can be multiplied by
    ``s`` in :data:`SCALES`, with the input domain or ``B`` scaled to match.

Infeasible (:func:`infeasible_instance`), one family each, the proof in the function's docstring:
    ``reach`` (a target beyond the analytic reachable set before the deadline), ``confidence``
    (a blind system whose covariance only grows, a target narrower than the prior allows),
    ``modes`` (a target reachable only by arriving in a mode that cannot move, or contradictory
    mode requirements), ``contradiction`` (two faces that cannot both hold at one step).

Every instance carries its tags (``state_dependent``, ``zero_slack``, ``unbounded``, ``flat``,
``multi_mode``, ...) and :meth:`Instance.describe` prints a reproducer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import norm

import idstlpy as stl

from .brute_force import Trace, chance_holds, sat
from .rollout import ModeSpec, mlo_rollout

__all__ = [
    "SCALES",
    "INFEASIBLE_FAMILIES",
    "Instance",
    "NoiseFunction",
    "feasible_instance",
    "active_perception_instance",
    "infeasible_instance",
]

SCALES = (1e-6, 1.0, 1e6)
INFEASIBLE_FAMILIES = ("reach", "confidence", "modes", "contradiction")


# ------------------------------------------------------------------------------------------------
# the instance


@dataclass
class Instance:
    """A problem with its construction.

    Attributes
    ----------
    family : str
    expect : str
        ``"feasible"`` or ``"infeasible"``.
    problem : stl.Problem
    modes : list of ModeSpec
        The modes as plain arrays (what was given to ``mk_lbs``), for :func:`mlo_rollout`.
    lo, hi : ndarray, shape (m,)
        The control domain ``lo <= u <= hi`` (infinite entries: unbounded sides).
    mean0, cov0 : ndarray
        The prior.
    formula : STLFormula
    scale : float
        The factor every length was multiplied by.
    tags : set of str
    witness : tuple (actions, controls) or None
        A plan the brute-force monitor accepts (feasible instances).
    why : str
        Why an infeasible instance has no plan.
    """

    family: str
    expect: str
    problem: Any
    modes: list[ModeSpec]
    lo: np.ndarray
    hi: np.ndarray
    mean0: np.ndarray
    cov0: np.ndarray
    formula: Any
    scale: float
    tags: set[str] = field(default_factory=set)
    witness: tuple[np.ndarray, np.ndarray] | None = None
    why: str = ""
    seed: int | None = None

    @property
    def witness_trace(self) -> Trace:
        assert self.witness is not None
        return mlo_rollout(self.modes, self.mean0, self.cov0, *self.witness)

    def describe(self) -> str:
        """A readable reproducer: dynamics, domain, prior, formula and its atoms, witness."""
        lines = [
            f"{self.expect} instance, family {self.family!r}, seed {self.seed}, scale {self.scale:g}, "
            f"tags {sorted(self.tags)}"
        ]
        for q, mode in enumerate(self.modes):
            lines.append(
                f"  mode {q} ({mode.label}): A={mode.A.tolist()} B={mode.B.tolist()} W={mode.W.tolist()} "
                f"C={None if mode.C is None else mode.C.tolist()} V={_show(mode.V)}"
            )
        lines.append(f"  domain: lo={self.lo.tolist()} hi={self.hi.tolist()}")
        lines.append(f"  prior: mean={self.mean0.tolist()} cov={self.cov0.tolist()}")
        lines.append(f"  formula: {self.formula}")
        for ap in self.formula.atomic_propositions():
            if ap.is_true or ap.is_false:
                continue
            preds = ", ".join(f"{p}" for p in ap.predicates)
            modes = None if ap.modes is None else sorted(ap.modes)
            lines.append(f"    {ap.name}: [{preds}] modes={modes}")
        if self.witness is not None:
            lines.append(f"  witness actions={self.witness[0].tolist()} controls={self.witness[1].tolist()}")
        if self.why:
            lines.append(f"  why infeasible: {self.why}")
        return "\n".join(lines)


def _show(V: Any) -> Any:
    if V is None or callable(V):
        return V
    return np.asarray(V).tolist()


class NoiseFunction:
    """A state-dependent observation noise ``n(x) = s * g(x[i] / s) * M`` (the ``V`` of ``mk_lbs``).

    ``g`` is ``a (y - centre)^2 + b`` (light-dark), ``a |y - centre| + b``, or the constant ``b``
    (a function that happens to be constant: the solver cannot know). Scaling the state by ``s``
    scales the noise by ``s``, so a problem and its scaled copy are the same problem in other units.
    """

    def __init__(self, kind: str, a: float, b: float, centre: float, coord: int, M: np.ndarray, s: float):
        self.kind, self.a, self.b, self.centre, self.coord = kind, a, b, centre, coord
        self.M = np.asarray(M, dtype=float)
        self.s = s

    def __call__(self, x: Any) -> np.ndarray:
        y = float(np.asarray(x, dtype=float)[self.coord]) / self.s
        if self.kind == "quadratic":
            g = self.a * (y - self.centre) ** 2 + self.b
        elif self.kind == "abs":
            g = self.a * abs(y - self.centre) + self.b
        else:
            g = self.b
        return (self.s * g) * self.M

    def __repr__(self) -> str:
        if self.kind == "constant":
            inner = f"{self.b:g}"
        else:
            sq = "**2" if self.kind == "quadratic" else ""
            f = "abs" if self.kind == "abs" else ""
            inner = f"{self.a:g}*{f}(x[{self.coord}]/{self.s:g} - {self.centre:g}){sq} + {self.b:g}"
        return f"lambda x: {self.s:g} * ({inner}) * {self.M.tolist()}"


# ------------------------------------------------------------------------------------------------
# building blocks


def _face(x: Any, h: np.ndarray, c: float, level: float) -> Any:
    """The chance constraint ``P[h'x + c <= 0] >= level``, written as a user would."""
    return stl.prob(x @ np.asarray(h, dtype=float) + float(c) <= 0) >= level


def _exact_face(x: Any, h: np.ndarray, c: float, level: float, states: list[tuple[np.ndarray, np.ndarray]]):
    """``_face`` with ``c`` lowered by the fewest ulps (doubling) that make the oracle accept ``states``.

    Zero slack computed in floating point may miss by a rounding error; the face is moved out by
    the smallest power-of-two multiple of ``c``'s ulp that the brute-force monitor accepts.
    """
    ulp = float(np.spacing(max(abs(c), 1e-300)))
    for i in range(64):
        shift = 0.0 if i == 0 else ulp * 2.0 ** (i - 1)
        pred = _face(x, h, c - shift, level)
        if all(chance_holds(pred.h, pred.c, pred.eps, m, S) for m, S in states):
            return pred
    raise AssertionError(f"could not place a face h={h} at zero slack on the witness")


def _level(rng: np.random.Generator) -> float:
    if rng.random() < 0.3:
        return float(rng.choice([0.5, 0.9, 0.95, 0.99]))
    return float(rng.uniform(0.5, 0.99))


def _direction(rng: np.random.Generator, n: int) -> np.ndarray:
    if rng.random() < 0.6:
        h = np.zeros(n)
        h[rng.integers(n)] = rng.choice([-1.0, 1.0])
        return h
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _mode_formula(q: Any, modes: set[int]) -> Any:
    items = [q == int(i) for i in sorted(modes)]
    return items[0] if len(items) == 1 else stl.logical_or(*items)


class _Names:
    def __init__(self) -> None:
        self.i = 0

    def __call__(self, stem: str = "p") -> str:
        self.i += 1
        return f"{stem}{self.i}"


@dataclass
class _System:
    modes: list[ModeSpec]
    lo: np.ndarray
    hi: np.ndarray
    n: int
    m: int
    tags: set[str]
    s_in: float = 1.0  # the unit of the inputs (the scale when the domain carries it)

    def build(self, mean0: np.ndarray, cov0: np.ndarray, formula: Any) -> Any:
        parts = []
        for spec in self.modes:
            if spec.C is None and not spec.W.any() and spec.label.endswith("lcs"):
                parts.append(stl.mk_lcs(spec.A, spec.B))
            elif spec.C is None:
                parts.append(stl.dynamical_system.mk_lbs(A=spec.A, B=spec.B, W=spec.W))
            else:
                parts.append(stl.dynamical_system.mk_lbs(A=spec.A, B=spec.B, W=spec.W, C=spec.C, V=spec.V))
        u = stl.mk_variable(self.m, name="u")
        cons = []
        for i in range(self.m):
            if np.isfinite(self.lo[i]):
                cons.append(u[i] >= float(self.lo[i]))
            if np.isfinite(self.hi[i]):
                cons.append(u[i] <= float(self.hi[i]))
        assert cons, "a control domain needs at least one constraint"
        domain = cons[0].region if len(cons) == 1 else stl.logical_and(*cons).region
        return stl.Problem(
            switched_system=stl.mk_switched_sys(parts),
            control_domain=domain,
            initial_state=stl.to_belief(mean=mean0, cov=cov0),
            stl_formula=formula,
        )


def _noise(rng: np.random.Generator, n: int, s: float, kind: str | None = None):
    """A sensor ``(C, V, tag)``: none, constant noise, or state-dependent noise."""
    kind = kind or str(rng.choice(["none", "const", "callable"], p=[0.35, 0.35, 0.3]))
    if kind == "none":
        return None, None, "no_sensor"
    p = int(rng.integers(1, n + 1))
    if rng.random() < 0.7:
        C = np.eye(n)[np.sort(rng.choice(n, size=p, replace=False))]
    else:
        C = rng.normal(size=(p, n))
    if kind == "const":
        return C, np.diag(rng.uniform(0.02, 0.3, size=p)) * s, "const_sensor"
    fkind = str(rng.choice(["quadratic", "abs", "constant"], p=[0.5, 0.25, 0.25]))
    V = NoiseFunction(
        fkind,
        a=float(rng.uniform(0.05, 0.2)),
        b=float(rng.uniform(0.01, 0.2)),
        centre=float(rng.uniform(-2, 2)),
        coord=int(rng.integers(n)),
        M=np.eye(p),
        s=s,
    )
    return C, V, "state_dependent"


def _process_noise(rng: np.random.Generator, n: int, s: float, allow: bool = True) -> np.ndarray:
    if not allow or rng.random() < 0.5:
        return np.zeros((n, n))
    return np.diag(rng.uniform(0.005, 0.05, size=n)) * s


def _random_dynamics(rng: np.random.Generator) -> tuple[str, np.ndarray, np.ndarray]:
    kind = str(rng.choice(["integrator", "double_integrator", "random"]))
    if kind == "integrator":
        n = int(rng.integers(1, 4))
        if rng.random() < 0.6:
            B = float(rng.uniform(0.5, 1.5)) * np.eye(n)
        else:
            B = rng.normal(size=(n, int(rng.integers(1, n + 1)))) * 0.7
        return kind, np.eye(n), B
    if kind == "double_integrator":
        d = int(rng.integers(1, 3))
        dt = float(rng.choice([0.5, 1.0]))
        A1 = np.array([[1.0, dt], [0.0, 1.0]])
        B1 = np.array([[0.5 * dt * dt], [dt]])
        return kind, np.kron(np.eye(d), A1), np.kron(np.eye(d), B1)
    n = int(rng.integers(1, 5))
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    eig = rng.uniform(0.6, 1.0, size=n)
    if rng.random() < 0.5:
        eig[0] = 1.0  # marginally stable
    A = Q @ np.diag(eig) @ Q.T
    B = rng.normal(size=(n, int(rng.integers(1, 3)))) * 0.7
    return kind, A, B


def _random_system(
    rng: np.random.Generator,
    s: float,
    *,
    noise: str | None = None,
    domain: str | None = None,
    num_modes: int | None = None,
    process_noise: bool = True,
) -> _System:
    """Random modes and a random control domain, every length multiplied by ``s``."""
    kind, A, B = _random_dynamics(rng)
    n, m = B.shape
    tags = {kind}
    domain = domain or str(rng.choice(["box", "unbounded", "flat"], p=[0.5, 0.25, 0.25]))
    if domain == "flat":
        B = np.hstack([B, rng.normal(size=(n, 1))])
        m += 1
    # Units: either the inputs carry the scale (domain * s) or B does.
    scale_input = bool(rng.random() < 0.5)
    B = B * (1.0 if scale_input else s)
    lo = -rng.uniform(0.3, 1.5, size=m)
    hi = rng.uniform(0.3, 1.5, size=m)
    if domain == "unbounded":
        which = int(rng.integers(m))
        if rng.random() < 0.5:
            hi[which] = np.inf
        else:
            lo[which] = -np.inf
        tags.add("unbounded")
    if domain == "flat":
        lo[-1] = hi[-1] = 0.0
        if rng.random() < 0.5:  # a free input next to the flat one
            lo[0] = -np.inf
            tags.add("unbounded")
        tags.add("flat")
    if domain == "off_centre":
        # The domain's centre far from 0 relative to its width, 0 still inside (issue 25's
        # u in [-0.0427, 1.7953]): shrinking it about the wrong point leaves it.
        width = rng.uniform(0.5, 2.0, size=m)
        inside = rng.uniform(0.01, 0.05, size=m) * width
        sign = np.where(rng.random(m) < 0.5, -1.0, 1.0)
        lo, hi = np.where(sign > 0, -inside, inside - width), np.where(sign > 0, width - inside, inside)
        tags.add("off_centre")
    if domain == "excludes_zero":
        # Some input must be away from 0 (u_i in [a, b] with 0 < a): idling is not free.
        which = int(rng.integers(m))
        a = rng.uniform(0.1, 0.5)
        b = a + rng.uniform(0.3, 1.0)
        lo[which], hi[which] = (a, b) if rng.random() < 0.5 else (-b, -a)
        tags.add("excludes_zero")
    if scale_input:
        lo, hi = lo * s, hi * s
    num_modes = num_modes or int(rng.integers(1, 3))
    modes = []
    for q in range(num_modes):
        Aq, Bq = A, B
        if q > 0:
            variant = str(rng.choice(["gain", "parked", "same", "other_A"]))
            if variant == "gain":
                Bq = B * float(rng.choice([0.5, 2.0]))
            elif variant == "parked":
                Bq = np.zeros_like(B)
            elif variant == "other_A":
                Qr, _ = np.linalg.qr(rng.normal(size=(n, n)))
                Aq = Qr @ np.diag(rng.uniform(0.7, 1.0, size=n)) @ Qr.T
            if variant != "same":
                tags.add("modes_differ")
        C, V, sensor = _noise(rng, n, s, noise)
        if C is not None and C.shape[0] < n:
            tags.add("partial_sensor")
        W = _process_noise(rng, n, s, process_noise)
        tags.add(sensor)
        if W.any():
            tags.add("process_noise")
        label = sensor
        if C is None and not W.any() and rng.random() < 0.5:
            label = "lcs"
        modes.append(ModeSpec(Aq, Bq, W, C, V, label=label))
    if num_modes > 1:
        tags.add("multi_mode")
    if not any(mm.state_dependent for mm in modes):
        tags.add("lp_exact")
    return _System(modes, lo, hi, n, m, tags, s if scale_input else 1.0)


def _sample_control(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, s_in: float) -> np.ndarray:
    u = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        a, b = lo[i], hi[i]
        if a == b:
            u[i] = a
        elif np.isfinite(a) and np.isfinite(b):
            u[i] = rng.choice([a, b]) if rng.random() < 0.3 else rng.uniform(a, b)
        elif np.isfinite(a):
            u[i] = rng.uniform(a, a + 3 * s_in)
        elif np.isfinite(b):
            u[i] = rng.uniform(b - 3 * s_in, b)
        else:
            u[i] = rng.uniform(-s_in, s_in)
    return u


def _prior(rng: np.random.Generator, n: int, s: float, point: bool | None) -> tuple[np.ndarray, np.ndarray]:
    mean = rng.uniform(-1, 1, size=n) * s
    if point is None:
        point = bool(rng.random() < 0.4)
    if point:
        return mean, np.zeros((n, n))
    sd = rng.uniform(0.02, 0.3, size=n) * s
    return mean, np.diag(sd**2)


# ------------------------------------------------------------------------------------------------
# feasible: a formula built around a roll-out


class _FormulaBuilder:
    """Random nested formulas that a given trace satisfies at given steps."""

    def __init__(self, rng: np.random.Generator, trace: Trace, x: Any, q: Any, num_modes: int, s: float):
        self.rng, self.trace, self.x, self.q = rng, trace, x, q
        self.num_modes, self.s = num_modes, s
        self.last = len(trace) - 1
        self.names = _Names()
        self.zero_slack = False
        self.features: set[str] = set()  # "release", "window_start" (an interval not from 0)
        self.n = trace.states[0][0].shape[0]

    def atom(self, S: set[int], *, free: bool = False) -> Any:
        """A named proposition holding at every step of ``S`` (``free``: around a random step, any truth)."""
        rng = self.rng
        steps = sorted(S)
        states = [self.trace.states[j] for j in steps]
        use_modes = self.num_modes > 1 and rng.random() < 0.4
        nf = int(rng.integers(1, 4))
        if use_modes and rng.random() < 0.25:
            nf = 0
        preds = []
        for _ in range(nf):
            h = _direction(rng, self.n)
            level = _level(rng)
            eps = _face(self.x, h, 0.0, level).eps
            z = float(norm.ppf(1.0 - eps))
            worst = max(float(h @ m) + z * float(np.sqrt(max(float(h @ S_ @ h), 0.0))) for m, S_ in states)
            if free:
                preds.append(_face(self.x, h, -worst + rng.uniform(-0.3, 0.3) * self.s, level))
                continue
            if rng.random() < 0.25:
                slack = 0.0
                self.zero_slack = True
            else:
                slack = float(rng.uniform(0.0, 0.3)) * self.s
            preds.append(_exact_face(self.x, h, -worst - slack, level, states))
        parts: list[Any] = list(preds)
        if use_modes:
            if free:
                needed: set[int] = set()
            else:
                needed = {self.trace.actions[j - 1] for j in steps if j >= 1}
            modes = set(needed)
            for extra in range(self.num_modes):
                if rng.random() < 0.3:
                    modes.add(extra)
            if not modes:
                modes.add(int(rng.integers(self.num_modes)))
            parts.append(_mode_formula(self.q, modes))
        return stl.logical_and(*parts, name=self.names())

    def free(self) -> Any:
        """A formula nobody needs: its truth is whatever the trace makes it."""
        a = self.atom({int(self.rng.integers(self.last + 1))}, free=True)
        if self.rng.random() < 0.3:
            lo = int(self.rng.integers(0, 3))
            return stl.eventually(lo, lo + int(self.rng.integers(0, 4)), a)
        return a

    def build(self, S: set[int], depth: int, top: bool = False) -> Any:
        rng = self.rng
        if not S:
            return self.free()
        if depth <= 0 or (not top and rng.random() < 0.25):
            return self.atom(S)
        # At the top the formula is temporal (one about the prior alone is a test of its own).
        ops = ["and", "or", "F", "G", "U", "R"]
        if top and depth == 1:
            op = str(rng.choice(ops[2:]))
        else:
            op = str(rng.choice(ops, p=[0.1, 0.1, 0.2, 0.2, 0.2, 0.2] if top else None))
        hi_S = max(S)
        room = self.last - hi_S
        if op == "R":
            self.features.add("release")
        # At the top, conjunctions and disjunctions are of temporal formulas (not of prior facts).
        sub = top and depth > 1
        if op == "and":
            return stl.logical_and(*[self.build(S, depth - 1, sub) for _ in range(int(rng.integers(2, 4)))])
        if op == "or":
            k = int(rng.integers(2, 4))
            parts: list[set[int]] = [set() for _ in range(k)]
            for j in S:
                parts[int(rng.integers(k))].add(j)
            return stl.logical_or(*[self.build(p, depth - 1, sub and bool(p)) for p in parts])
        if op in ("F", "U"):
            a = int(rng.integers(0, min(room, 3) + 1))
            d = {j: int(rng.integers(a, min(self.last - j, a + 6) + 1)) for j in S}
            extra = int(rng.choice([0, 0, 1, 2, 5, 30]))
            b = max(d.values()) + extra
            if a:
                self.features.add("window_start")
            right = self.build({j + d[j] for j in S}, depth - 1)
            if op == "F":
                return stl.eventually(a, b, right)
            T1 = {i for j in S for i in range(j + a, j + d[j])}
            return stl.until(self.build(T1, depth - 1), a, b, right)
        if op == "G":
            a = int(rng.integers(0, min(room, 3) + 1))
            b = int(rng.integers(a, room + 1))
            if a:
                self.features.add("window_start")
            T = {i for j in S for i in range(j + a, j + b + 1)}
            return stl.always(a, b, self.build(T, depth - 1))
        # release: per step, the right side on the whole window, or up to a step where the left holds
        a = int(rng.integers(0, min(room, 3) + 1))
        b = a + int(rng.integers(0, 6))
        if a:
            self.features.add("window_start")
        T1: set[int] = set()
        T2: set[int] = set()
        for j in S:
            if j + b <= self.last and rng.random() < 0.4:
                T2.update(range(j + a, j + b + 1))
            else:
                k1 = int(rng.integers(j + a, min(j + b, self.last) + 1))
                T1.add(k1)
                T2.update(range(j + a, k1 + 1))
        return stl.release(self.build(T1, depth - 1), a, b, self.build(T2, depth - 1))


def feasible_instance(
    seed: int,
    *,
    scale: float | None = None,
    noise: str | None = None,
    domain: str | None = None,
    num_modes: int | None = None,
    point_prior: bool | None = None,
    process_noise: bool = True,
    max_depth: int = 3,
    obstacle: bool = False,
) -> Instance:
    """A random problem with a plan by construction (see the module docstring).

    Parameters
    ----------
    seed : int
        Everything is drawn from ``numpy.random.default_rng(seed)``.
    scale : float, optional
        Multiply every length by it (default: drawn from :data:`SCALES`, mostly 1).
    noise : {"none", "const", "callable"}, optional
        Force one kind of sensor on every mode.
    domain : {"box", "unbounded", "flat", "off_centre", "excludes_zero"}, optional
        The last two only when asked: a box whose centre is far from 0 relative to its width (0
        inside), and a box one of whose inputs excludes 0.
    num_modes : int, optional
    point_prior : bool, optional
    process_noise : bool
        Allow process noise ``W``.
    max_depth : int
        Deepest operator nesting.
    obstacle : bool
        Also avoid a box obstacle the witness avoids, all along the plan: ``G[0,T] (P[x_i <= l_i]
        or P[x_i >= h_i] or ...)``, a disjunction at every step (:func:`_obstacle`).
    """
    rng = np.random.default_rng(seed)
    s = float(scale) if scale is not None else float(rng.choice(SCALES, p=[0.2, 0.6, 0.2]))
    system = _random_system(
        rng, s, noise=noise, domain=domain, num_modes=num_modes, process_noise=process_noise
    )
    mean0, cov0 = _prior(rng, system.n, s, point_prior)
    N = int(rng.integers(2, 13))
    actions = rng.integers(len(system.modes), size=N)
    controls = np.array([_sample_control(rng, system.lo, system.hi, system.s_in) for _ in range(N)])
    trace = mlo_rollout(system.modes, mean0, cov0, actions, controls)
    x = stl.mk_variable(system.n, name="x")
    q = stl.mk_variable(len(system.modes), dtype=int)
    builder = _FormulaBuilder(rng, trace, x, q, len(system.modes), s)
    formula = builder.build({0}, int(rng.integers(1, max_depth + 1)), top=True)
    tags = set(system.tags)
    if obstacle:
        formula = stl.logical_and(formula, stl.always(0, N, _obstacle(rng, trace, x, s)))
        tags.add("obstacle")
    assert sat(formula, 0, trace), "generator bug: the witness does not satisfy the formula"
    if not cov0.any():
        tags.add("point_prior")
    if builder.zero_slack:
        tags.add("zero_slack")
    tags |= builder.features
    if s != 1.0:
        tags.add("scaled")
    inst = Instance(
        family="roll_out",
        expect="feasible",
        problem=system.build(mean0, cov0, formula),
        modes=system.modes,
        lo=system.lo,
        hi=system.hi,
        mean0=mean0,
        cov0=cov0,
        formula=formula,
        scale=s,
        tags=tags,
        witness=(np.asarray(actions, dtype=int), controls),
        seed=seed,
    )
    # The witness in the problem's own terms: controls inside the domain, the oracle satisfied.
    assert np.all(controls >= system.lo) and np.all(controls <= system.hi)
    assert sat(inst.formula, 0, inst.witness_trace)
    return inst


def _obstacle(rng: np.random.Generator, trace: Trace, x: Any, s: float) -> Any:
    """A box obstacle the witness avoids at every step, as the disjunction of its outer faces.

    The box lies across the witness's span (its centre drawn among the span's points, its half
    widths up to half the span) and is shrunk until, at every step, some face ``P[x_i <= l_i]`` or
    ``P[x_i >= h_i]`` holds at the drawn level (checked with the brute-force monitor's
    :func:`~oracles.brute_force.chance_holds`), so the avoidance is a real disjunction: which face
    holds changes along the path where the box sits in the middle of it.
    """
    n = trace.states[0][0].shape[0]
    means = np.array([m for m, _ in trace.states])
    low, high = means.min(axis=0), means.max(axis=0)
    span = np.maximum(high - low, 0.2 * s)
    level = float(rng.choice([0.5, 0.8, 0.9]))
    centre = low + rng.random(n) * (high - low) + rng.normal(size=n) * 0.2 * span
    half = rng.uniform(0.05, 0.5, size=n) * span
    eye = np.eye(n)
    for _ in range(60):
        faces = []
        for i in range(n):
            faces.append(_face(x, eye[i], -(centre[i] - half[i]), level))  # x_i <= centre - half
            faces.append(_face(x, -eye[i], centre[i] + half[i], level))  # x_i >= centre + half
        if all(any(chance_holds(f.h, f.c, f.eps, m, S) for f in faces) for m, S in trace.states):
            return stl.logical_or(*[stl.logical_and(f, name=f"wall{j}") for j, f in enumerate(faces)])
        half *= 0.7
    # A box too close to the path everywhere: put it beside the path in coordinate 0.
    gap = 0.5 * span[0]
    return stl.logical_or(
        stl.logical_and(_face(x, eye[0], -(high[0] + 10 * gap), level), name="wall0"),
        stl.logical_and(_face(x, -eye[0], high[0] + 11 * gap, level), name="wall1"),
    )


def active_perception_instance(seed: int, *, scale: float | None = None) -> Instance:
    """A light-dark problem built around a detour to the light: the sampler's kind of problem.

    An integrator whose sensor is useless far from a light at ``x_0 = l`` (noise
    ``a (x_0 - l)^2 + b``) starts uncertain at the origin. The witness drives to the light at full
    speed, lingers, drives back and holds still; the target is a box around where it holds, as
    tight as the witness's covariance there allows (plus a slack ``>= 0``, sometimes 0), and the
    free space a band around its whole path: ``free U[0,T] G[0,h] target``.
    """
    rng = np.random.default_rng(seed)
    s = float(scale) if scale is not None else float(rng.choice(SCALES, p=[0.2, 0.6, 0.2]))
    n = int(rng.integers(1, 3))
    g = float(rng.uniform(0.5, 1.0))
    scale_input = bool(rng.random() < 0.5)
    s_in = s if scale_input else 1.0
    B = g * np.eye(n) * (1.0 if scale_input else s)
    umax = rng.uniform(0.5, 1.0, size=n) * s_in
    light = float(rng.uniform(2.5, 4.5))
    V = NoiseFunction(
        "quadratic", float(rng.uniform(0.05, 0.15)), float(rng.uniform(0.002, 0.02)), light, 0, np.eye(n), s
    )
    modes = [ModeSpec(np.eye(n), B, np.zeros((n, n)), np.eye(n), V, label="state_dependent light")]
    mean0 = np.zeros(n)
    cov0 = np.diag(rng.uniform(0.2, 0.4, size=n) ** 2) * s * s
    # The witness: to the light (the last step lands on it), linger, back to the origin, hold.
    step = float(B[0, 0] * umax[0])
    controls: list[np.ndarray] = []
    pos = 0.0
    for target in (light * s, 0.0):
        while abs(target - pos) > 1e-12 * s:
            move = float(np.clip(target - pos, -step, step))
            u = np.zeros(n)
            u[0] = move / B[0, 0]
            controls.append(u)
            pos += move
        if target != 0.0:
            controls.extend(np.zeros(n) for _ in range(int(rng.integers(1, 4))))
    K = len(controls)
    h = int(rng.integers(1, 4))
    controls.extend(np.zeros(n) for _ in range(h))
    actions = np.zeros(len(controls), dtype=int)
    U = np.array(controls)
    trace = mlo_rollout(modes, mean0, cov0, actions, U)
    x = stl.mk_variable(n, name="x")
    zero_slack = False

    def faces(steps: range, level: float, slack_max: float) -> list[Any]:
        nonlocal zero_slack
        states = [trace.states[j] for j in steps]
        out = []
        for j in range(n):
            for sign in (-1.0, 1.0):
                hvec = sign * np.eye(n)[j]
                z = float(norm.ppf(level))
                worst = max(
                    float(hvec @ m) + z * float(np.sqrt(max(float(hvec @ S @ hvec), 0.0))) for m, S in states
                )
                slack = 0.0 if rng.random() < 0.25 else float(rng.uniform(0, slack_max))
                zero_slack = zero_slack or slack == 0.0
                out.append(_exact_face(x, hvec, -worst - slack, level, states))
        return out

    level = float(rng.uniform(0.8, 0.97))
    sd_hold = float(np.sqrt(max(trace.states[K][1][0, 0], 0.0)))
    target = stl.logical_and(*faces(range(K, K + h + 1), level, 0.5 * sd_hold), name="target")
    free = stl.logical_and(*faces(range(0, K), 0.99, 0.5 * s), name="free_space")
    extra = int(rng.choice([0, 5, 20]))
    formula = stl.until(free, 0, K + extra, stl.always(0, h, target))
    assert sat(formula, 0, trace), "generator bug: the witness does not satisfy the formula"
    tags = {"active_perception", "state_dependent", "integrator"}
    if zero_slack:
        tags.add("zero_slack")
    if s != 1.0:
        tags.add("scaled")
    lo, hi = -umax, umax.copy()
    system = _System(modes, lo, hi, n, n, tags, s_in)
    return Instance(
        family="active_perception",
        expect="feasible",
        problem=system.build(mean0, cov0, formula),
        modes=modes,
        lo=lo,
        hi=hi,
        mean0=mean0,
        cov0=cov0,
        formula=formula,
        scale=s,
        tags=tags,
        witness=(actions, U),
        seed=seed,
    )


# ------------------------------------------------------------------------------------------------
# infeasible: constructions with a proof


def _wrap(rng: np.random.Generator, depth: int, extra: Callable[[], Any]) -> tuple[Callable[[Any], Any], int]:
    """A random context ``C[.]`` and a deadline ``D``: ``C[g]`` at step 0 implies ``g`` at some ``k <= D``.

    F[a,b] X and X' U[a,b] X need X at some step in ``[a, b]`` (deadline ``b + D_X``); G[a,b] X and
    X' R[a,b] X need X at step ``a`` (both readings of release include ``k + a``: deadline
    ``a + D_X``); X & Y needs X; X | Y needs one of them (deadline ``max``). ``extra()`` gives the
    other operands, whose truth does not matter.
    """
    if depth <= 0:
        return (lambda g: g), 0
    inner, D = _wrap(rng, depth - 1, extra)
    # The innermost operator is temporal, so every wrapped formula looks past step 0.
    op = str(rng.choice(["F", "U", "G", "R"] if depth == 1 else ["F", "U", "G", "R", "and", "or"]))
    a = int(rng.integers(0, 3))
    b = a + int(rng.integers(0, 6))
    if op == "F":
        return (lambda g: stl.eventually(a, b, inner(g))), D + b
    if op == "U":
        left = extra()
        return (lambda g: stl.until(left, a, b, inner(g))), D + b
    if op == "G":
        return (lambda g: stl.always(a, b, inner(g))), D + a
    if op == "R":
        left = extra()
        return (lambda g: stl.release(left, a, b, inner(g))), D + a
    if op == "and":
        other = extra()
        first = bool(rng.random() < 0.5)
        return (lambda g: stl.logical_and(inner(g), other) if first else stl.logical_and(other, inner(g))), D
    second, D2 = _wrap(rng, depth - 1, extra)
    return (lambda g: stl.logical_or(inner(g), second(g))), max(D, D2)


def _extra_atoms(rng: np.random.Generator, x: Any, names: _Names, mean0: np.ndarray, s: float):
    def make() -> Any:
        h = _direction(rng, mean0.shape[0])
        c = -float(h @ mean0) + rng.uniform(-1.0, 2.0) * s
        return stl.logical_and(_face(x, h, c, _level(rng)), name=names("e"))

    return make


def _integrator_system(
    rng: np.random.Generator, s: float, *, double: bool, domain: str, gains: list[float], noise: bool = True
) -> tuple[_System, float]:
    """Integrators ``x' = x + g_q u`` (or double integrators, dt = 1) whose input 0 is at most ``hi``.

    Returns the system and ``hi`` (the largest value input 0 may take), both in scaled units.
    """
    scale_input = bool(rng.random() < 0.5)
    if double:
        n, m = 2, 1
        A = np.array([[1.0, 1.0], [0.0, 1.0]])
        Bs = [np.array([[0.0], [g]]) for g in gains]
    else:
        n = int(rng.integers(1, 3))
        m = n
        A = np.eye(n)
        Bs = [g * np.eye(n) for g in gains]
    if domain == "flat":
        Bs = [np.hstack([B, rng.normal(size=(n, 1))]) for B in Bs]
        m += 1
    Bs = [B * (1.0 if scale_input else s) for B in Bs]
    hi = rng.uniform(0.3, 1.5, size=m)
    lo = -rng.uniform(0.3, 1.5, size=m)
    tags = {"double_integrator" if double else "integrator"}
    if domain == "unbounded":
        lo[0] = -np.inf  # input 0 may be as negative as it likes; only its upper bound matters
        tags.add("unbounded")
    if domain == "flat":
        lo[-1] = hi[-1] = 0.0
        tags.add("flat")
    if scale_input:
        lo, hi = lo * s, hi * s
    modes = []
    for B in Bs:
        C, V, sensor = _noise(rng, n, s) if noise else (None, None, "no_sensor")
        W = _process_noise(rng, n, s)
        tags.add(sensor)
        modes.append(ModeSpec(A, B, W, C, V, label=sensor))
    if len(modes) > 1:
        tags.add("multi_mode")
    if not any(mm.state_dependent for mm in modes):
        tags.add("lp_exact")
    return _System(modes, lo, hi, n, m, tags), float(hi[0])


def _infeasible_reach(rng: np.random.Generator, s: float, names: _Names):
    """A target beyond the reachable set before the deadline.

    Proof. Under the MLO dynamics the mean obeys ``mean' = A mean + B u`` whatever the noise. With
    ``x' = x + g_q u`` and ``u_0 <= hi`` (``g_q >= 0``), the mean of ``x_0`` at step ``k`` is at most
    ``x_0(0) + k g_max hi``; for the double integrator ``p' = p + v``, ``v' = v + g_q u`` it is at most
    ``p(0) + k v(0) + g_max hi k (k - 1) / 2``. ``P[x_0 >= t] >= 1 - eps`` with ``eps <= 0.5`` needs
    ``mean_0 >= t + z sd >= t``. The context implies the goal at some step ``k <= D`` (see ``_wrap``),
    and ``t`` exceeds the bound at every ``k <= D``: no plan.
    """
    double = bool(rng.random() < 0.4)
    domain = str(rng.choice(["box", "unbounded", "flat"]))
    gains = [float(g) for g in rng.uniform(0.3, 1.5, size=int(rng.integers(1, 3)))]
    system, hi = _integrator_system(rng, s, double=double, domain=domain, gains=gains)
    mean0, cov0 = _prior(rng, system.n, s, None)
    gmax_hi = max(float(sp.B[1 if double else 0, 0]) for sp in system.modes) * hi
    x = stl.mk_variable(system.n, name="x")
    q = stl.mk_variable(len(system.modes), dtype=int)
    ctx, D = _wrap(rng, int(rng.integers(1, 4)), _extra_atoms(rng, x, names, mean0, s))
    if double:
        p0, v0 = mean0
        bound = max(p0 + k * v0 + gmax_hi * k * (k - 1) / 2 for k in range(D + 1))
    else:
        bound = mean0[0] + D * gmax_hi
    gap = float(rng.choice([1e-4, 0.05, 0.3, 1.0])) * s
    t = bound + gap
    e0 = np.eye(system.n)[0]
    parts = [_face(x, -e0, t, _level(rng))]
    if len(system.modes) > 1 and rng.random() < 0.3:
        parts.append(_mode_formula(q, {int(rng.integers(len(system.modes)))}))
    goal = stl.logical_and(*parts, name=names("goal"))
    why = f"mean of x[0] is at most {bound:.6g} at every step <= {D}, the goal needs >= {t:.6g}"
    return system, mean0, cov0, ctx(goal), why


def _infeasible_confidence(rng: np.random.Generator, s: float, names: _Names):
    """A blind system whose covariance only grows; a target narrower than the prior's spread.

    Proof. No mode has a sensor, so ``cov' = A cov A' + W W'``. With ``A = I`` this is
    ``cov_k = cov_0 + sum W W' >= cov_0``; for the double integrator with a diagonal prior,
    ``var(p_k) >= var(p_0) + k^2 dt^2 var(v_0) >= var(p_0)``. Either way ``sd_k >= sd_0`` along the
    target's coordinate. ``lo <= x_i`` at level ``1 - e1`` and ``x_i <= hi`` at ``1 - e2`` need
    ``hi - lo >= (z1 + z2) sd_k >= (z1 + z2) sd_0``, and the target's width is below that. Confidence
    1 (``eps = 0``) on one face needs zero variance, and ``sd_k >= sd_0 > 0``. The context implies the
    target at some step: no plan.
    """
    double = bool(rng.random() < 0.3)
    num_modes = int(rng.integers(1, 3))
    if double:
        dt = float(rng.choice([0.5, 1.0]))
        A = np.array([[1.0, dt], [0.0, 1.0]])
        B = np.array([[0.5 * dt * dt], [dt]])
        coord = 0
    else:
        n = int(rng.integers(1, 4))
        A = np.eye(n)
        B = rng.normal(size=(n, int(rng.integers(1, n + 1))))
        coord = int(rng.integers(n))
    n, m = B.shape
    domain = str(rng.choice(["box", "unbounded"]))
    lo = -rng.uniform(0.3, 1.5, size=m) * s
    hi = rng.uniform(0.3, 1.5, size=m) * s
    tags = {"double_integrator" if double else "integrator", "no_sensor", "lp_exact"}
    if domain == "unbounded":
        hi[:] = np.inf
        tags.add("unbounded")
    modes = []
    for qq in range(num_modes):
        Bq = B * (1.0 if qq == 0 else float(rng.choice([0.0, 0.5, 2.0])))
        W = _process_noise(rng, n, s)
        lcs = not W.any() and rng.random() < 0.5
        modes.append(ModeSpec(A, Bq, W, None, None, label="lcs" if lcs else "no_sensor"))
    if num_modes > 1:
        tags.add("multi_mode")
    system = _System(modes, lo, hi, n, m, tags)
    mean0 = rng.uniform(-1, 1, size=n) * s
    sd0 = rng.uniform(0.05, 0.5, size=n) * s
    cov0 = np.diag(sd0**2)
    x = stl.mk_variable(n, name="x")
    e = np.eye(n)[coord]
    if rng.random() < 0.2:
        sign = float(rng.choice([-1.0, 1.0]))
        bound = sign * mean0[coord] + float(rng.uniform(0, 2)) * s  # sign * x_i <= bound at confidence 1
        faces = [_face(x, sign * e, -bound, 1.0)]
        why = f"confidence 1 needs var(x[{coord}]) = 0, and it is >= {sd0[coord] ** 2:.6g} at every step"
    else:
        l1, l2 = float(rng.uniform(0.6, 0.99)), float(rng.uniform(0.6, 0.99))
        z1, z2 = float(norm.ppf(l1)), float(norm.ppf(l2))
        width = (z1 + z2) * sd0[coord] * float(rng.choice([0.0, rng.uniform(0.0, 0.98), 0.98]))
        centre = mean0[coord] + rng.uniform(-1, 1) * s
        low, high = centre - width / 2, centre + width / 2
        faces = [_face(x, -e, low, l1), _face(x, e, -high, l2)]
        why = (
            f"width {high - low:.6g} < (z1 + z2) sd0 = {(z1 + z2) * sd0[coord]:.6g}: "
            f"sd of x[{coord}] never shrinks without a sensor"
        )
    goal = stl.logical_and(*faces, name=names("target"))
    ctx, _ = _wrap(rng, int(rng.integers(1, 4)), _extra_atoms(rng, x, names, mean0, s))
    return system, mean0, cov0, ctx(goal), why


def _infeasible_modes(rng: np.random.Generator, s: float, names: _Names):
    """Mode requirements the dynamics forbid.

    (a) Mode 0 moves (``x' = x + g u``, ``u_0 <= hi``), mode 1 is parked (``B = 0``). The goal is
    ``q == 1 & P[x_0 >= t]``: at step ``k >= 1`` it needs arrival in mode 1, so ``x_k = x_{k-1}``, whose
    mean is at most ``x_0(0) + (k - 1) g hi``; at step 0 the mean is ``x_0(0) < t``. With
    ``t > x_0(0) + (D - 1) g hi`` (reachable at step ``D`` in mode 0, so only the mode is wrong) and
    the goal needed at some ``k <= D``: no plan.

    (b) ``G[a,b] q == 0`` and ``F[a2,b2] q == 1`` with ``1 <= a <= a2 <= b2 <= b``: every step of
    ``[k + a2, k + b2]`` is ``>= 1``, so its arrival mode is constrained to be both 0 and 1. The core
    is unsatisfiable at every step, so any context that needs it somewhere is too.
    """
    x_names = names
    if rng.random() < 0.5:
        domain = str(rng.choice(["box", "unbounded", "flat"]))
        g = float(rng.uniform(0.3, 1.5))
        system, hi = _integrator_system(rng, s, double=False, domain=domain, gains=[g, 0.0])
        system.modes[1].label += " parked"
        mean0, cov0 = _prior(rng, system.n, s, None)
        x = stl.mk_variable(system.n, name="x")
        q = stl.mk_variable(2, dtype=int)
        ctx, D = _wrap(rng, int(rng.integers(1, 4)), _extra_atoms(rng, x, x_names, mean0, s))
        step = float(system.modes[0].B[0, 0]) * hi
        t = mean0[0] + max(D - 1, 0) * step + float(rng.uniform(1e-3, 1.0)) * step
        e0 = np.eye(system.n)[0]
        goal = stl.logical_and(_face(x, -e0, t, _level(rng)), q == 1, name=names("goal"))
        why = f"arriving in mode 1 (parked) the mean of x[0] is at most {mean0[0] + max(D - 1, 0) * step:.6g}"
        return system, mean0, cov0, ctx(goal), why
    system = _random_system(rng, s, num_modes=2)
    mean0, cov0 = _prior(rng, system.n, s, None)
    x = stl.mk_variable(system.n, name="x")
    q = stl.mk_variable(2, dtype=int)
    a = int(rng.integers(1, 4))
    b = a + int(rng.integers(0, 5))
    a2 = int(rng.integers(a, b + 1))
    b2 = int(rng.integers(a2, b + 1))
    extra = _extra_atoms(rng, x, x_names, mean0, s)
    g0 = stl.logical_and(q == 0, name=names("stay"))
    g1 = stl.logical_and(q == 1, name=names("switch"))
    core = stl.logical_and(stl.always(a, b, g0), stl.eventually(a2, b2, g1))
    ctx, _ = _wrap(rng, int(rng.integers(0, 3)), extra)
    why = f"G[{a},{b}] q == 0 and F[{a2},{b2}] q == 1 need two modes at one step"
    return system, mean0, cov0, ctx(core), why


def _infeasible_contradiction(rng: np.random.Generator, s: float, names: _Names):
    """Two chance constraints that cannot hold at one step.

    Proof. ``P[h'x >= t] >= 1 - e1`` needs ``h'mean >= t + z1 sd >= t`` and ``P[h'x <= t - gap] >= 1 - e2``
    needs ``h'mean <= t - gap - z2 sd < t`` (``z >= 0`` for ``eps <= 0.5``, ``gap > 0``). Either both
    faces sit in one proposition (an empty belief cone), or ``G[a,b] A & F[a2,b2] B`` with
    ``[a2, b2]`` inside ``[a, b]`` puts them at one step. The core is unsatisfiable at every step.
    """
    system = _random_system(rng, s)
    mean0, cov0 = _prior(rng, system.n, s, None)
    x = stl.mk_variable(system.n, name="x")
    h = _direction(rng, system.n)
    t = float(h @ mean0) + float(rng.uniform(-1, 1)) * s
    gap = float(rng.choice([1e-6, 1e-3, 0.1, 1.0])) * s
    up = _face(x, -h, t, _level(rng))  # h'x >= t
    down = _face(x, h, -(t - gap), _level(rng))  # h'x <= t - gap
    depth = int(rng.integers(0, 3))
    if rng.random() < 0.35:
        core = stl.logical_and(up, down, name=names("empty"))
        depth = max(depth, 1)
    else:
        a = int(rng.integers(0, 4))
        b = a + int(rng.integers(0, 5))
        a2 = int(rng.integers(a, b + 1))
        b2 = int(rng.integers(a2, b + 1))
        A_ = stl.logical_and(down, name=names("below"))
        B_ = stl.logical_and(up, name=names("above"))
        core = stl.logical_and(stl.always(a, b, A_), stl.eventually(a2, b2, B_))
    ctx, _ = _wrap(rng, depth, _extra_atoms(rng, x, names, mean0, s))
    why = f"h'x >= {t:.6g} and h'x <= {t - gap:.6g} at one step, h = {h.tolist()}"
    return system, mean0, cov0, ctx(core), why


def infeasible_instance(seed: int, *, family: str | None = None, scale: float | None = None) -> Instance:
    """A random problem with no plan, by one of :data:`INFEASIBLE_FAMILIES` (proofs in their docstrings)."""
    rng = np.random.default_rng(seed)
    family = family or str(rng.choice(INFEASIBLE_FAMILIES))
    s = float(scale) if scale is not None else float(rng.choice(SCALES, p=[0.2, 0.6, 0.2]))
    make = {
        "reach": _infeasible_reach,
        "confidence": _infeasible_confidence,
        "modes": _infeasible_modes,
        "contradiction": _infeasible_contradiction,
    }[family]
    system, mean0, cov0, formula, why = make(rng, s, _Names())
    tags = set(system.tags)
    if not cov0.any():
        tags.add("point_prior")
    if s != 1.0:
        tags.add("scaled")
    return Instance(
        family=family,
        expect="infeasible",
        problem=system.build(mean0, cov0, formula),
        modes=system.modes,
        lo=system.lo,
        hi=system.hi,
        mean0=mean0,
        cov0=cov0,
        formula=formula,
        scale=s,
        tags=tags,
        why=why,
        seed=seed,
    )
