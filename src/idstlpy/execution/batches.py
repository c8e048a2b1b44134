"""Running a batch of Monte Carlo executions in one worker (a process, a thread, or in-process).

A worker receives a :class:`Payload` (what runs: the model, the plan, the executor's settings,
the re-planning policy) and the seeds of its runs, and returns one record per run (the monitor's,
:func:`~idstlpy.execution.monitor.run_record`). Runs are executed together as arrays
(:func:`execute_batch`: the executor's step law over a batch, every run drawing from its own
generator, :class:`RunStreams`), or one at a time (:func:`~idstlpy.execution.simulation.simulate`,
or :func:`~idstlpy.execute` when the runs re-plan, or for a step-function plant). Everything
here is at module level so that process pools can pickle it; :func:`serialise` chooses how the
payload travels (module notes of :mod:`idstlpy.execution.validation`).
"""

from __future__ import annotations

import dataclasses
import logging
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InvalidArgumentError
from ..executor import ExecutorSpec, PlantStep, ProcessNoise, StepLaw
from ..formulas import STLFormula
from ..markov import MarkovSwitching, switching_of
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .jumps import execute_jump_batch
from .monitor import batch_monitor, promises, run_record
from .simulation import simulate

if TYPE_CHECKING:
    from ..dynamical_system import LCS, SwitchedSystem
    from ..sets import Polytope
    from ..synthesis.problem import Problem
    from .policy import ReplanPolicy

__all__ = ["Payload", "RunStreams", "batch_size", "execute_batch", "execute_runs", "run_batch", "serialise"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Payload:
    """What a worker needs to execute runs (picklable, unless the model is not).

    Attributes
    ----------
    system : SwitchedSystem or None
        The planning model; None when ``factory`` rebuilds the problem in the worker.
    formula : STLFormula or None
        The formula (None with ``factory``).
    factory : callable or None
        A picklable zero-argument callable returning an equivalent problem.
    plan : ProbabilisticTSTrajectory
        The plan executed.
    real_system : SwitchedSystem, LCS or None
        The linear plant (None: the model, or ``plant``).
    real_initial_state : ndarray, shape (n,)
        The true start of runs without a start of their own.
    num_of_steps : int
        Steps per run.
    control_domain : Polytope or None
        The inputs' projection (None: unclipped).
    process_noise : {"model", "real", "none"}
        The disturbance of the true state.
    gains : tuple
        Per mode, the tracking gains (resolved once by ``validate``).
    plant : callable or None
        A step-function plant.
    keep : int
        Runs with an index below this keep their trajectories.
    problem : Problem or None
        The problem re-solved when the runs re-plan (None with ``factory``).
    policy : ReplanPolicy or None
        The re-planning policy (None: the runs follow the plan).
    batched : bool
        Execute the runs together as arrays (when neither ``policy`` nor ``plant`` is set).
    batch_size : int
        Most runs executed together.
    """

    system: SwitchedSystem | None
    formula: STLFormula | None
    factory: Callable[[], Problem] | None
    plan: ProbabilisticTSTrajectory
    real_system: SwitchedSystem | LCS | None
    real_initial_state: np.ndarray
    num_of_steps: int
    control_domain: Polytope | None
    process_noise: ProcessNoise
    gains: tuple[Sequence[np.ndarray], ...]
    plant: PlantStep | None
    keep: int
    problem: Problem | None = None
    policy: ReplanPolicy | None = None
    batched: bool = True
    batch_size: int = 4096

    def executor_spec(self, system: SwitchedSystem, modes: Sequence[int] | None = None) -> ExecutorSpec:
        """The executor of the runs, on ``system`` (the payload's, or the factory's)."""
        return ExecutorSpec.make(
            system,
            control_domain=self.control_domain,
            process_noise=self.process_noise,
            lqr_gains=list(self.gains),
            real_system=self.real_system,
            plant=self.plant,
            modes=modes,
        )


def execute_runs(
    payload: Payload,
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Run the executions of one batch (``first_index`` is the index of ``seeds[0]``).

    ``starts`` (one row per seed) are the runs' true starts; None: ``payload.real_initial_state``.
    """
    problem = payload.problem
    if payload.system is None:
        problem = payload.factory()  # type: ignore[misc]
        system, formula = problem.switched_system, problem.stl_formula
    else:
        system, formula = payload.system, payload.formula
    if formula is None:
        raise InvalidArgumentError("formula: a batch needs the formula its runs are judged on, got None")
    promised = promises(formula, payload.plan, payload.num_of_steps + 1)
    switching = switching_of(system)
    if switching is not None:  # chance switching (issue 35): the runs of execution/jumps.py
        return _jump_runs(payload, system, switching, formula, promised, seeds, first_index, starts)
    # (a plant step function draws from the generator it is given: one run at a time)
    if payload.policy is None and payload.batched and payload.plant is None:
        results: list[dict[str, Any]] = []
        size = payload.batch_size
        for lo in range(0, len(seeds), size):
            part = seeds[lo : lo + size]
            x0s = None if starts is None else starts[lo : lo + size]
            results.extend(execute_batch(payload, system, formula, promised, part, first_index + lo, x0s))
        return results
    spec = payload.executor_spec(system)
    results = []
    taken: dict[int, dict[str, Any]] = {}
    if payload.policy is not None and payload.batched and payload.plant is None and problem is not None:
        taken = _vouched_batch(payload, system, formula, promised, seeds, first_index, starts, spec)
    for offset, ss in enumerate(seeds):
        if offset in taken:
            results.append(taken[offset])
            continue
        x0 = payload.real_initial_state if starts is None else starts[offset]
        if payload.policy is not None:
            from .replanning import execute

            if problem is None:
                raise InvalidArgumentError("problem: re-planning runs need the problem to re-solve, got None")
            # execute draws from default_rng(ss): the same noise as simulate below
            run = execute(problem, payload.plan, None, x0, seed=ss, policy=payload.policy, spec=spec)
            res = run_record(formula, promised, run.belief, run.real)
            res["replans"] = run.num_replans
            xi = (run.belief, run.real)
        else:
            rng = np.random.default_rng(ss)
            xi = simulate(system, payload.plan, payload.num_of_steps, x0, None, seed=rng, spec=spec)
            res = run_record(formula, promised, *xi)
        if first_index + offset < payload.keep:
            res["trajectories"] = xi
        results.append(res)
    return results


def _jump_runs(
    payload: Payload,
    system: SwitchedSystem,
    switching: MarkovSwitching,
    formula: STLFormula,
    promised: list[np.ndarray],
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None,
) -> list[dict[str, Any]]:
    """The runs of a batch under chance switching, ``payload.batch_size`` at a time."""
    if payload.policy is not None:
        raise InvalidArgumentError("policy: re-planning under chance switching is not supported yet")
    spec = payload.executor_spec(system)  # every mode may execute: every mode's gains
    results: list[dict[str, Any]] = []
    size = payload.batch_size
    for lo in range(0, len(seeds), size):
        part = seeds[lo : lo + size]
        x0s = (
            np.tile(payload.real_initial_state, (len(part), 1))
            if starts is None
            else np.asarray(starts[lo : lo + size], dtype=float)
        )
        keep = max(0, min(len(part), payload.keep - first_index - lo))
        results.extend(
            execute_jump_batch(
                spec, switching, formula, promised, payload.plan, payload.num_of_steps, x0s, part, keep
            )
        )
    return results


def batch_size(steps: int, n: int, most: int) -> int:
    """Runs per batch: ``most``, fewer when ``runs x (steps + 1) x n^2`` exceeds 4e6 (>= 16)."""
    return int(max(16, min(most, 4_000_000 // max(1, (steps + 1) * n * n))))


class RunStreams:
    """A stand-in for the generator of the step law over ``S`` runs: row ``i`` of every draw
    comes from run ``i``'s own generator ``default_rng(seeds[i])``, in the order the run would
    draw alone, so a run executed in a batch gets the noise :func:`simulate` gives it.

    The runs' normals are drawn ahead in blocks (one call per run and block); drawing more
    than a run uses changes nothing, its generator is its own.

    Parameters
    ----------
    seeds : sequence of SeedSequence
        The runs' seeds.
    ahead : int
        Normals drawn per run and block.
    """

    def __init__(self, seeds: Sequence[np.random.SeedSequence], ahead: int) -> None:
        self._gens = [np.random.default_rng(ss) for ss in seeds]
        self._ahead = max(1, int(ahead))
        self._buf = np.empty((len(self._gens), 0))
        self._pos = 0

    def standard_normal(self, size: tuple[int, int]) -> np.ndarray:
        """Draws of shape ``size = (S, r)``, row ``i`` from run ``i``'s generator."""
        S, r = size
        if S != len(self._gens):  # pragma: no cover - the law always draws one row per run
            raise InvalidArgumentError(f"expected a draw for {len(self._gens)} runs, got {S}")
        if self._pos + r > self._buf.shape[1]:
            fresh = np.empty((S, max(r, self._ahead)))
            for i, gen in enumerate(self._gens):
                gen.standard_normal(out=fresh[i])
            self._buf = np.hstack([self._buf[:, self._pos :], fresh])
            self._pos = 0
        out = self._buf[:, self._pos : self._pos + r]
        self._pos += r
        return out


def _draws_per_run(law: StepLaw) -> int:
    """The normals one run draws along the law's steps (process noise, then the sensor's)."""
    total = 0
    for st in law.steps:
        if st.W is not None:
            total += st.W.shape[1]
        if st.model.p:
            total += st.model.noise(st.mean).shape[1]
    return total


@dataclass
class _Rolled:
    """The arrays of a batch of runs, time-major: (L, S, ...)."""

    means: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    covs: np.ndarray  # (L, n, n) shared by the runs while the sensor noise is constant, else (L, S, n, n)
    shared: bool
    observations: np.ndarray  # (L, keep, p_max): only of the runs that keep their trajectories


def _roll(
    law: StepLaw,
    payload: Payload,
    seeds: Sequence[np.random.SeedSequence],
    starts: np.ndarray | None,
    keep: int,
) -> _Rolled:
    """Advance all the runs together with the step law (each from its own stream)."""
    plan, N = payload.plan, payload.num_of_steps
    S, n, m = len(seeds), law.spec.system.n, law.spec.system.m
    rng = RunStreams(seeds, _draws_per_run(law))
    X = np.tile(payload.real_initial_state, (S, 1)) if starts is None else np.array(starts, dtype=float)
    M = np.tile(plan.get_mean(0), (S, 1))
    P: np.ndarray = plan.get_cov(0).copy()
    means, states, controls = np.empty((N + 1, S, n)), np.empty((N + 1, S, n)), np.empty((N, S, m))
    covs: list[np.ndarray] = [P]
    observations = np.full((N + 1, keep, law.p_max), np.nan)
    means[0], states[0] = M, X
    for k in range(N):
        U = law.control(k, M)
        X = law.plant(k, X, U, rng)  # type: ignore[arg-type]
        Y = law.observe(k, X, rng)  # type: ignore[arg-type]
        M, P = law.filter(k, M, P, U, Y)
        means[k + 1], states[k + 1], controls[k] = M, X, U
        covs.append(P)
        if Y is not None and keep:
            observations[k + 1, :, : Y.shape[1]] = Y[:keep]
        if not (np.isfinite(M).all() and np.isfinite(X).all()):
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
    shared = all(c.ndim == 2 for c in covs)
    cov_arr = np.stack(covs) if shared else np.stack([np.broadcast_to(c, (S, n, n)) for c in covs])
    return _Rolled(means, states, controls, cov_arr, shared, observations)


def execute_batch(
    payload: Payload,
    system: SwitchedSystem,
    formula: STLFormula,
    promised: list[np.ndarray],
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None,
) -> list[dict[str, Any]]:
    """Execute ``len(seeds)`` runs together with the step law over a batch, then monitor them
    together; the same records as :func:`execute_runs`'s one-run-at-a-time loop (up to rounding).

    Arrays are kept time-major, (L, S, ...), so each step writes one contiguous block and the
    monitor reads contiguous traces.
    """
    plan, N, S = payload.plan, payload.num_of_steps, len(seeds)
    law = StepLaw(payload.executor_spec(system, plan.get_action()[:N].tolist()), plan, N)
    keep = max(0, min(S, payload.keep - first_index))
    r = _roll(law, payload, seeds, starts, keep)
    return _records(payload, formula, promised, r, keep)


def _records(
    payload: Payload, formula: STLFormula, promised: list[np.ndarray], r: _Rolled, keep: int
) -> list[dict[str, Any]]:
    """The records of a batch's rolled runs (monitored together)."""
    plan, N, S = payload.plan, payload.num_of_steps, r.means.shape[1]
    actions = plan.get_action()[:N]
    belief = batch_monitor(formula, promised, r.means, r.covs, actions)
    state = batch_monitor(formula, promised, r.states, None, actions)
    b_props, b_preds = belief["props"].tolist(), belief["preds"].tolist()
    s_props, s_preds = state["props"].tolist(), state["preds"].tolist()
    b_margin, s_margin = belief["margin"].tolist(), state["margin"].tolist()
    b_ors, s_ors = belief["ors"].tolist(), state["ors"].tolist()
    results: list[dict[str, Any]] = []
    for i in range(S):
        res: dict[str, Any] = {
            "belief_margin": b_margin[i],
            "state_margin": s_margin[i],
            "belief_props": b_props[i],
            "belief_preds": b_preds[i],
            "state_props": s_props[i],
            "state_preds": s_preds[i],
            "belief_ors": b_ors[i],
            "state_ors": s_ors[i],
        }
        if i < keep:
            run_covs = r.covs if r.shared else r.covs[:, i]
            controls = r.controls[:, i]
            res["trajectories"] = (
                ProbabilisticTSTrajectory(r.means[:, i].copy(), np.array(run_covs), actions, controls.copy()),
                RealTrajectory(r.states[:, i].copy(), r.observations[:, i].copy(), actions, controls.copy()),
            )
        results.append(res)
    return results


def run_batch(
    blob: bytes, seeds: Sequence[np.random.SeedSequence], first_index: int, starts: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """Worker entry point: unpickle the payload, then :func:`execute_runs`."""
    return execute_runs(pickle.loads(blob), seeds, first_index, starts)


def serialise(payload: Payload, problem_factory: Callable[[], Problem] | None) -> bytes | None:
    """Bytes loadable by ``pickle.loads`` in a worker, or None when the problem cannot travel."""
    try:
        return pickle.dumps(payload)
    except Exception as exc:  # noqa: BLE001 - any pickling failure sends us to the next option
        logger.debug("validate: payload not picklable (%s)", exc)
    try:
        import cloudpickle  # type: ignore[import-not-found, unused-ignore]

        blob: bytes = cloudpickle.dumps(payload)
        return blob
    except Exception as exc:  # noqa: BLE001
        logger.debug("validate: cloudpickle unavailable or failed (%s)", exc)
    if problem_factory is not None:
        slim = dataclasses.replace(payload, system=None, formula=None, factory=problem_factory, problem=None)
        try:
            return pickle.dumps(slim)
        except Exception as exc:  # noqa: BLE001
            raise InvalidArgumentError(
                f"problem_factory must be picklable (a module-level function or functools.partial): {exc}"
            ) from exc
    return None


def _vouched_batch(
    payload: Payload,
    system: SwitchedSystem,
    formula: STLFormula,
    promised: list[np.ndarray],
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None,
    spec: ExecutorSpec,
) -> dict[int, dict[str, Any]]:
    """The records of the runs (by offset) whose every scheduled check the plan's shared
    prediction vouches for (:func:`~idstlpy.execution.vouch.vouched_runs`): executed together
    as the fixed plan, they are the runs ``execute`` makes with the policy (no check decides
    anything; up to rounding, as the batched fixed-plan runs are ``simulate``'s). The other runs
    are left to ``execute``. Only for a policy whose only decisions are scheduled risk checks on
    the sound bound (no drift test, no start check)."""
    from .vouch import check_reference, vouched_runs

    policy = payload.policy
    if (
        policy is None
        or policy.trigger != "on_risk"
        or policy.drift is not None
        or policy.start_resolves
        or policy.risk_measure != "bound"
        or payload.num_of_steps != payload.plan.num_of_steps
    ):
        return {}
    ref = check_reference(spec, payload.plan, formula)
    if ref is None:
        return {}
    plan, N, S = payload.plan, payload.num_of_steps, len(seeds)
    law = StepLaw(payload.executor_spec(system, plan.get_action()[:N].tolist()), plan, N)
    keep = max(0, min(S, payload.keep - first_index))
    r = _roll(law, payload, seeds, starts, keep)
    ok = vouched_runs(ref, policy, r.means, r.covs, plan.get_action()[:N])
    records = _records(payload, formula, promised, r, keep)
    taken = {}
    for i in np.flatnonzero(ok).tolist():
        records[i]["replans"] = 0
        taken[i] = records[i]
    logger.debug("validate: %d of %d runs vouched for at every check (batched)", len(taken), S)
    return taken
