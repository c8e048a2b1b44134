"""Random problems with joint chance constraints that have a plan *by construction* (issue 32.3).

Every problem is built around a witness first: random small dynamics (one or two modes, process
noise, with or without a sensor), a box control domain, a Gaussian prior and a random admissible
roll-out (modes and controls inside the domain, 3-10 steps), rolled out by the independent
:func:`oracles.rollout.mlo_rollout`. The formula is then written around that roll-out, one joint
chance constraint ``prob_in(region) >= 1 - eps`` per part:

``stay``
    ``G[a, b] prob_in(region)`` (often from step 0, so the prior itself must meet it).
``goal``
    ``F[a, b] prob_in(region)`` met by the witness at one step of the window.
``dwell``
    ``F[a, b] G[0, d] prob_in(region)``.

Each region is an axis-aligned box or has 3-6 faces with random normals. At every step the part
needs, a random split of ``eps`` among the faces (a Dirichlet draw, a different one per step)
fixes how far each face must be from the witness's mean; each face's offset is the tightest over
those steps, then moved out by a random slack (zero now and then). The witness's Boole bound is
then at most ``eps`` at every such step: the monitor's reading of a joint constraint, so
``stl.satisfies`` accepts the witness (checked here). Because the split changes from step to
step, no single per-face allocation fixed in advance need suit every step: the case the issue
reports.

:func:`witness_probabilities` is the independent check: the region's probability at each needed
step by Monte Carlo (and by :func:`scipy.stats.multivariate_normal.cdf` for boxes), and the
literal Boole sum with :mod:`scipy.stats.norm`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import multivariate_normal, norm

import idstlpy as stl
from idstlpy.chance import joint_slack
from idstlpy.formulas import FALSE, TRUE, STLAnd, STLAtomicProposition, STLOr, STLRelease, STLUntil

from .brute_force import Trace, chance_holds
from .joint import boole_risk, sampled_probability
from .rollout import ModeSpec, mlo_rollout

__all__ = ["JointPart", "JointInstance", "joint_instance", "joint_sat", "plan_check", "witness_probabilities"]


@dataclass
class JointPart:
    """One joint chance constraint of the formula and the steps at which the witness meets it."""

    kind: str
    H: np.ndarray  # (F, n)
    c: np.ndarray  # (F,)
    eps: float
    steps: list[int]


@dataclass
class JointInstance:
    """A problem with its witness plan.

    Attributes
    ----------
    seed : int
    problem : stl.Problem
    modes : list of ModeSpec
    mean0, cov0 : ndarray, shapes (n,), (n, n)
    actions : ndarray, shape (K,)
    controls : ndarray, shape (K, m)
    means, covs : ndarray, shapes (K + 1, n), (K + 1, n, n)
        The witness's belief trace (independent roll-out).
    formula : STLFormula
    parts : list of JointPart
    """

    seed: int
    problem: Any
    modes: list[ModeSpec]
    mean0: np.ndarray
    cov0: np.ndarray
    actions: np.ndarray
    controls: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    formula: Any
    parts: list[JointPart] = field(default_factory=list)

    def witness(self) -> stl.ProbabilisticTSTrajectory:
        """The witness plan as a belief trajectory (for ``stl.satisfies``)."""
        return stl.ProbabilisticTSTrajectory(self.means, self.covs, self.actions, self.controls)

    def describe(self) -> str:
        """A one-line summary."""
        kinds = ", ".join(f"{p.kind}({p.H.shape[0]} faces, eps={p.eps:.3g})" for p in self.parts)
        return (
            f"seed {self.seed}: n={self.means.shape[1]}, {len(self.modes)} mode(s), "
            f"witness {len(self.actions)} steps; {kinds}"
        )


def _spd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    M = rng.normal(size=(n, n))
    S = M @ M.T / n + 0.2 * np.eye(n)
    return scale * S / float(np.trace(S) / n)


def _modes(rng: np.random.Generator, n: int, m: int) -> list[ModeSpec]:
    out = []
    for _ in range(int(rng.integers(1, 3))):
        A = np.eye(n) + 0.05 * rng.normal(size=(n, n))
        B = 0.3 * np.eye(n, m) + 0.1 * rng.normal(size=(n, m))
        W = np.sqrt(rng.uniform(0.0005, 0.01)) * np.eye(n)
        if rng.random() < 0.5:
            C = np.eye(n)
            V = np.sqrt(rng.uniform(0.005, 0.1)) * np.eye(n)
            out.append(ModeSpec(A, B, W, C, V))
        else:
            out.append(ModeSpec(A, B, W))
    return out


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Face normals: an axis-aligned box (3 in 10) or 3-6 random unit normals."""
    if rng.random() < 0.3:
        return np.vstack([np.eye(n), -np.eye(n)])
    V = rng.normal(size=(int(rng.integers(3, 7)), n))
    return np.asarray(V / np.linalg.norm(V, axis=1, keepdims=True), dtype=float)


def _region(
    rng: np.random.Generator,
    x: Any,
    means: np.ndarray,
    covs: np.ndarray,
    steps: list[int],
    level: float,
    kind: str,
) -> tuple[Any, JointPart]:
    """A joint constraint at ``level`` that the beliefs at ``steps`` meet (Boole, per-step split)."""
    n = means.shape[1]
    H = _directions(rng, n)
    F = H.shape[0]
    eps = (stl.prob_in(stl.Polytope(H, np.zeros(F)), variable=x) >= level).eps
    d_min = np.zeros(F)
    offs = np.full(F, np.inf)
    for k in steps:
        split = np.maximum(rng.dirichlet(np.full(F, 0.7)), 1e-3)
        split = split / split.sum()
        sd = np.sqrt(np.einsum("fi,ij,fj->f", H, covs[k], H))
        need = norm.ppf(1.0 - eps * split) * sd  # the face's distance from the mean at this split
        d_min = np.maximum(d_min, need)
        offs = np.minimum(offs, -(H @ means[k]) - need)
    sd0 = float(np.sqrt(np.mean([np.trace(covs[k]) / n for k in steps])))
    slack = float(rng.choice([0.0, 1e-6, 1e-3, 0.02, 0.1])) * sd0
    c = offs - slack * rng.random(F)
    # Zero slack computed in floating point may miss by a rounding error: move the faces out by
    # the fewest ulps (doubling) that the monitor's reading accepts at every step. The reading is
    # taken over the whole trace, as the monitor takes it: its root search stops within 1e-12 of
    # the scale of each step's bracket, on the feasible side (a margin of -1e-12 at zero slack).
    ulp = np.spacing(np.maximum(np.abs(c), 1e-300))
    for i in range(64):
        shifted = c - (0.0 if i == 0 else 2.0 ** (i - 1)) * ulp
        if np.all(joint_slack(H, shifted, eps, means, covs)[steps] >= 0):
            c = shifted
            break
    part = JointPart(kind, H, c, eps, list(steps))
    joint = stl.prob_in(stl.Polytope(H, c), variable=x) >= level
    return joint, part


def joint_instance(seed: int) -> JointInstance:
    """A random problem with ``prob_in`` constraints and a witness plan the monitor accepts.

    Parameters
    ----------
    seed : int

    Returns
    -------
    JointInstance

    Raises
    ------
    AssertionError
        When the monitor rejects the witness (a construction bug, never expected).
    """
    rng = np.random.default_rng(seed)
    n = int(rng.choice([2, 2, 3]))
    m = n
    modes = _modes(rng, n, m)
    mean0 = rng.normal(size=n)
    cov0 = _spd(rng, n, float(rng.uniform(0.005, 0.05)))
    K = int(rng.integers(3, 11))
    actions = rng.integers(0, len(modes), size=K)
    controls = rng.uniform(-0.8, 0.8, size=(K, m))
    trace = mlo_rollout(modes, mean0, cov0, actions, controls)
    means = np.array([s[0] for s in trace.states])
    covs = np.array([s[1] for s in trace.states])
    x = stl.mk_variable(n)
    levels = [0.8, 0.9, 0.95, 0.99]
    parts: list[JointPart] = []
    pieces = []
    kinds = ["stay"] + [str(k) for k in rng.choice(["goal", "dwell", "stay"], size=int(rng.integers(0, 3)))]
    for kind in kinds:
        level = float(rng.choice(levels))
        if kind == "stay":
            a = 0 if rng.random() < 0.7 else int(rng.integers(0, K))
            b = int(rng.integers(a, K + 1))
            joint, part = _region(rng, x, means, covs, list(range(a, b + 1)), level, kind)
            pieces.append(stl.always(a, b, stl.logical_and(joint, name=f"stay{len(parts)}")))
        elif kind == "goal":
            a = int(rng.integers(0, K))
            b = int(rng.integers(a, K + 1))
            k = int(rng.integers(a, b + 1))
            joint, part = _region(rng, x, means, covs, [k], level, kind)
            pieces.append(stl.eventually(a, b, stl.logical_and(joint, name=f"goal{len(parts)}")))
        else:
            d = int(rng.integers(1, 3))
            if K < d:
                continue
            k = int(rng.integers(0, K - d + 1))
            a = int(rng.integers(0, k + 1))
            joint, part = _region(rng, x, means, covs, list(range(k, k + d + 1)), level, kind)
            pieces.append(
                stl.eventually(a, k, stl.always(0, d, stl.logical_and(joint, name=f"dwell{len(parts)}")))
            )
        parts.append(part)
    formula = pieces[0] if len(pieces) == 1 else stl.logical_and(*pieces)
    u = stl.mk_variable(m, name="u")
    domain = stl.logical_and(*[p for i in range(m) for p in (u[i] >= -1.0, u[i] <= 1.0)]).region
    systems = [
        stl.dynamical_system.mk_lbs(A=s.A, B=s.B, W=s.W)
        if s.C is None
        else stl.dynamical_system.mk_lbs(A=s.A, B=s.B, W=s.W, C=s.C, V=s.V)
        for s in modes
    ]
    problem = stl.Problem(stl.mk_switched_sys(systems), domain, stl.to_belief(mean=mean0, cov=cov0), formula)
    inst = JointInstance(seed, problem, modes, mean0, cov0, actions, controls, means, covs, formula, parts)
    if not stl.satisfies(inst.witness(), formula):
        raise AssertionError(f"the monitor rejects the witness of {inst.describe()}")
    return inst


def witness_probabilities(inst: JointInstance, samples: int = 20000, seed: int = 0) -> list[dict[str, float]]:
    """The independent reading of every part at every step the witness meets it.

    Returns
    -------
    list of dict
        Per (part, step): ``eps``, ``boole`` (the literal Boole sum), ``mc`` / ``mc_low`` /
        ``mc_high`` (the region's probability by sampling, 99.99% Wilson interval) and, for a
        region whose faces are the n coordinate boxes' only, ``exact`` (the multivariate normal
        CDF of the box).
    """
    rng = np.random.default_rng(seed)
    out = []
    for part in inst.parts:
        for k in part.steps:
            mean, cov = inst.means[k], inst.covs[k]
            est, lo, hi = sampled_probability(part.H, part.c, mean, cov, samples, rng)
            row = {
                "eps": part.eps,
                "boole": boole_risk(part.H, part.c, mean, cov),
                "mc": est,
                "mc_low": lo,
                "mc_high": hi,
            }
            n = mean.shape[0]
            if part.H.shape[0] == 2 * n and np.array_equal(part.H, np.vstack([np.eye(n), -np.eye(n)])):
                # x_i <= -c_i and -x_i <= -c_{n+i}: the box [c_{n+i}, -c_i]
                lo_b, hi_b = part.c[n:], -part.c[:n]
                mvn = multivariate_normal(mean=mean, cov=cov)
                row["exact"] = float(mvn.cdf(hi_b, lower_limit=lo_b))
            out.append(row)
    return out


# ------------------------------------------------------------------------------------------------
# an independent monitor for formulas with joint constraints


def _atom_holds(ap: STLAtomicProposition, k: int, trace: Trace) -> bool:
    """Single chance constraints by their deterministic equivalent, each joint constraint by the
    literal Boole sum (``scipy.stats.norm``) at most its ``eps`` (the monitor's reading)."""
    if ap is FALSE:
        return False
    if ap is TRUE:
        return True
    mean, cov = trace.states[k]
    for p in ap.predicates[: ap.num_single]:
        if not chance_holds(p.h, p.c, p.eps, mean, cov):
            return False
    for j in ap.joints:
        # the bound may sit on eps to rounding (zero-slack witnesses): a relative 1e-9 of eps
        if boole_risk(j.H, j.c, mean, cov) > j.eps * (1 + 1e-9):
            return False
    return not (ap.modes is not None and k > 0 and trace.actions[k - 1] not in ap.modes)


def joint_sat(formula: Any, k: int, trace: Trace) -> bool:
    """``trace |=_k formula`` by the literal definitions, joint constraints read by Boole's bound."""
    if k >= len(trace):
        return False
    if isinstance(formula, STLAtomicProposition):
        return _atom_holds(formula, k, trace)
    if isinstance(formula, STLAnd):
        return all(joint_sat(c, k, trace) for c in formula.children)
    if isinstance(formula, STLOr):
        return any(joint_sat(c, k, trace) for c in formula.children)
    if isinstance(formula, STLUntil):
        f1, f2, a, b = formula.left, formula.right, formula.a, formula.b
        return any(
            joint_sat(f2, k1, trace) and all(joint_sat(f1, k2, trace) for k2 in range(k + a, k1))
            for k1 in range(k + a, k + b + 1)
        )
    if isinstance(formula, STLRelease):
        f1, f2, a, b = formula.left, formula.right, formula.a, formula.b
        for k1 in range(k + a, k + b + 1):
            if joint_sat(f1, k1, trace) and all(joint_sat(f2, k2, trace) for k2 in range(k + a, k1 + 1)):
                return True
        return all(joint_sat(f2, k1, trace) for k1 in range(k + a, k + b + 1))
    raise TypeError(f"unknown formula type {type(formula).__name__}")


def plan_check(inst: JointInstance, plan: stl.ProbabilisticTSTrajectory) -> tuple[bool, bool]:
    """A returned plan judged twice: ``(monitor, oracle)``.

    ``monitor`` is ``stl.satisfies`` on the plan's own beliefs; ``oracle`` re-rolls the plan's
    modes and controls with the independent :func:`oracles.rollout.mlo_rollout` and judges the
    original formula with :func:`joint_sat`.
    """
    monitor = bool(stl.satisfies(plan, inst.formula))
    trace = mlo_rollout(inst.modes, inst.mean0, inst.cov0, plan.get_action(), plan.get_control())
    return monitor, joint_sat(inst.formula, 0, trace)
