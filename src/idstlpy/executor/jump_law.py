"""The executor's step law under chance switching, for given executed mode sequences (issue 35).

The executor layer's part of :mod:`idstlpy.execution.jumps`: given the executed mode of every run
and step (drawn by the execution layer from the chain, or fixed by the bound of
:mod:`idstlpy.executor.markov_bound`), every step ``k`` applies the step law
(:class:`~idstlpy.executor.StepLaw`) of the executed mode ``s_k`` for the plant and the sensor,
and of

- ``s_k`` for the tracking gain and the Kalman filter when the executed mode is observed;
- the commanded ``q_k`` when it is not (the executor believes its command; the observation it
  receives is ``s_k``'s sensor's, which must then have the dimension of every other mode's).

One law per mode is bound to the plan (the plan's means and inputs with every step in that
mode), so a step is the same arithmetic as a run without jumps in that mode. Runs that share an
executed mode at a step are advanced together; every run keeps its own filter covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidArgumentError
from ..formulas import STLFormula
from ..semantics import atom_margins, formula_margins
from ..trajectory import ProbabilisticTSTrajectory
from .law import StepLaw
from .spec import ExecutorSpec

__all__ = ["JumpRoll", "check_unobserved", "mode_laws", "roll_executed", "success_of"]


@dataclass
class JumpRoll:
    """A batch of ``S`` runs with jumps, time-major.

    Attributes
    ----------
    means : ndarray, shape (L, S, n)
        Filter means.
    covs : ndarray, shape (L, S, n, n)
        Filter covariances (each run its own).
    states : ndarray, shape (L, S, n)
        True states.
    controls : ndarray, shape (L - 1, S, m)
        Applied inputs.
    executed : ndarray of int, shape (S, L - 1)
        The executed mode of every run and step.
    observations : ndarray, shape (L, keep, p_max)
        Observations of the first ``keep`` runs (NaN where none).
    """

    means: np.ndarray
    covs: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    executed: np.ndarray
    observations: np.ndarray


def mode_laws(spec: ExecutorSpec, plan: ProbabilisticTSTrajectory, steps: int) -> list[StepLaw]:
    """One step law per mode: the plan's means and inputs with every step in that mode."""
    N_ref = plan.num_of_steps
    out = []
    for j in range(spec.system.num_modes):
        in_j = ProbabilisticTSTrajectory(
            plan.get_mean(), plan.get_cov(), np.full(N_ref, j, dtype=int), plan.get_control()
        )
        out.append(StepLaw(spec, in_j, steps))
    return out


def check_unobserved(spec: ExecutorSpec) -> None:
    """An unobserved chain needs one output dimension for all modes (the filter reads any)."""
    dims = {mode.p for mode in spec.system.system_modes}
    if len(dims) > 1:
        raise InvalidArgumentError(
            "switching: an unobserved executed mode needs every mode to have the same output "
            f"dimension (the filter of the commanded mode reads the executed mode's sensor), got "
            f"{sorted(dims)}; declare the switching observed=True"
        )


def roll_executed(
    spec: ExecutorSpec,
    plan: ProbabilisticTSTrajectory,
    executed: np.ndarray,
    observed: bool,
    starts: np.ndarray,
    rng: np.random.Generator,
    keep: int = 0,
    initial_mean: np.ndarray | None = None,
    initial_cov: np.ndarray | None = None,
) -> JumpRoll:
    """Execute ``S`` runs of a plan whose executed modes are ``executed`` (S, N).

    Parameters
    ----------
    spec : ExecutorSpec
        The executor; its gains must cover every executed mode.
    plan : ProbabilisticTSTrajectory
        The plan (commanded modes, means, inputs); ``N <= plan.num_of_steps`` steps run.
    executed : ndarray of int, shape (S, N)
        The executed mode of every run and step.
    observed : bool
        Whether the executor knows the executed mode (module notes).
    starts : ndarray, shape (S, n)
        True initial states.
    rng : numpy.random.Generator
        The noises.
    keep : int
        Runs whose observations are kept.
    initial_mean : ndarray, shape (n,), optional
        Filter prior mean (default the plan's first).
    initial_cov : ndarray, shape (n, n), optional
        Filter prior covariance (default the plan's first).

    Returns
    -------
    JumpRoll
    """
    if not observed:
        check_unobserved(spec)
    S, N = executed.shape
    n = starts.shape[1]
    m = spec.system.m
    laws = mode_laws(spec, plan, N)
    commanded = plan.get_action()[:N]
    p_max = laws[0].p_max if laws else 0
    X = np.array(starts, dtype=float)
    M = np.tile(plan.get_mean(0) if initial_mean is None else initial_mean, (S, 1))
    P0 = plan.get_cov(0) if initial_cov is None else initial_cov
    # Runs that all execute one sequence share their filter covariance while the sensor noise is
    # constant (the step law keeps it (n, n) then); otherwise each run has its own.
    shared = bool((executed == executed[:1]).all())
    P = np.array(P0, dtype=float) if shared else np.broadcast_to(P0, (S, n, n)).copy()
    means, states = np.empty((N + 1, S, n)), np.empty((N + 1, S, n))
    covs = np.empty((N + 1, S, n, n))
    controls = np.empty((N, S, m))
    observations = np.full((N + 1, keep, p_max), np.nan)
    means[0], states[0], covs[0] = M, X, P
    for k in range(N):
        q = int(commanded[k])
        for j in np.unique(executed[:, k]).tolist():
            idx = np.flatnonzero(executed[:, k] == j)
            act = laws[j] if observed else laws[q]  # what the executor believes
            U = act.control(k, M[idx])
            Xj = laws[j].plant(k, X[idx], U, rng)
            Y = laws[j].observe(k, Xj, rng)
            if shared:  # one group of all the runs, in order
                Mj, P = act.filter(k, M, P, U, Y)
                shared = P.ndim == 2  # (a state-dependent sensor made the runs' covariances differ)
                X, M, controls[k] = Xj, Mj, U
            else:
                Mj, Pj = act.filter(k, M[idx], P[idx], U, Y)
                X[idx], M[idx], controls[k, idx] = Xj, Mj, U
                P[idx] = Pj if Pj.ndim == 3 else Pj[None]
            if Y is not None and keep:
                mine = idx < keep
                if mine.any():
                    observations[k + 1, idx[mine], : Y.shape[1]] = Y[mine]
        if not (np.isfinite(M).all() and np.isfinite(X).all()):
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
        means[k + 1], states[k + 1], covs[k + 1] = M, X, P  # (a shared P broadcast over the runs)
    return JumpRoll(means, covs, states, controls, np.array(executed, dtype=int), observations)


def success_of(formula: STLFormula, means: np.ndarray, covs: np.ndarray | None) -> np.ndarray:
    """Whether each of ``S`` traces satisfies ``formula`` (S,) bool.

    ``means`` (L, S, n); ``covs`` (L, S, n, n) for the executed belief, None for the true states
    (the deterministic reading). Mode propositions are not read (callers refuse them).
    """
    L, S, n = means.shape
    flat_means = means.reshape(L * S, n)
    flat_covs = np.zeros((L * S, n, n)) if covs is None else covs.reshape(L * S, n, n)
    atoms: dict[int, np.ndarray] = {}
    for ap in formula.atomic_propositions():
        if id(ap) in atoms:
            continue
        if ap.is_false:
            atoms[id(ap)] = np.full((L, S), -np.inf)
        elif not ap.predicates:
            atoms[id(ap)] = np.full((L, S), np.inf)
        else:
            actions = np.zeros(L * S - 1, dtype=int)  # (mode propositions are refused upstream)
            atoms[id(ap)] = atom_margins(ap, flat_means, flat_covs, actions).reshape(L, S)
    return np.asarray(formula_margins(formula, atoms, L)[0] >= 0.0)
