"""Execution with chance switching: the executed mode jumps by the system's Markov chain.

Used by :func:`~idstlpy.execution.simulation.simulate` (one run) and by
:func:`~idstlpy.validate`'s batches when the system carries a
:class:`~idstlpy.markov.MarkovSwitching` (:func:`~idstlpy.markov.with_switching`); a system
without one never reaches this module.

Each run first draws its executed sequence ``s`` (N,) from the chain under the plan's commands,
then every step ``k`` applies the executor's step law (:class:`~idstlpy.executor.StepLaw`) of
the executed mode ``s_k`` for the plant and the sensor, and of

- ``s_k`` for the tracking gain and the Kalman filter when the executed mode is observed;
- the commanded ``q_k`` when it is not (the executor believes its command; the observation it
  receives is ``s_k``'s sensor's, which must then have the dimension of every other mode's).

One law per mode is bound to the plan (the plan's means and inputs with every step in that
mode), so the step is the same arithmetic as a run without jumps in that mode. Runs that share
an executed mode at a step are advanced together; every run keeps its own filter covariance.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..executor import ExecutorSpec
from ..executor.jump_law import JumpRoll, roll_executed
from ..formulas import STLFormula
from ..markov import MarkovSwitching
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .monitor import batch_monitor

__all__ = ["execute_jump_batch", "roll_jumps"]


def roll_jumps(
    spec: ExecutorSpec,
    plan: ProbabilisticTSTrajectory,
    steps: int,
    switching: MarkovSwitching,
    starts: np.ndarray,
    rng: np.random.Generator,
    keep: int = 0,
    initial_mean: np.ndarray | None = None,
    initial_cov: np.ndarray | None = None,
) -> JumpRoll:
    """Execute ``S`` runs of a plan under chance switching.

    Parameters
    ----------
    spec : ExecutorSpec
        The executor; its gains must cover every mode (``ExecutorSpec.make(..., modes=None)``).
    plan : ProbabilisticTSTrajectory
        The plan (commanded modes, means, inputs).
    steps : int
        Steps executed, ``N``.
    switching : MarkovSwitching
        The chain of the executed mode.
    starts : ndarray, shape (S, n)
        True initial states.
    rng : numpy.random.Generator
        The noises; the executed sequences come from a stream it spawns.
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
    commanded = plan.get_action()[:steps]
    # The executed modes from a child stream (spawning leaves ``rng``'s state alone), so the
    # noises are those of the run without jumps: a chain that never jumps reproduces it.
    executed = switching.draw(commanded, rng.spawn(1)[0], starts.shape[0])
    return roll_executed(
        spec, plan, executed, switching.observed, starts, rng, keep, initial_mean, initial_cov
    )


def execute_jump_batch(
    spec: ExecutorSpec,
    switching: MarkovSwitching,
    formula: STLFormula,
    promised: list[np.ndarray],
    plan: ProbabilisticTSTrajectory,
    steps: int,
    starts: np.ndarray,
    seeds: Sequence[np.random.SeedSequence],
    keep: int,
) -> list[dict[str, Any]]:
    """The records of a batch of runs under chance switching (``validate``'s, see batches).

    The batch draws from one generator seeded by its first run's seed (the executed sequences,
    then the noises), so a run's noise depends on its batch: the report is reproducible for a
    given seed and batch size, but a run is not the one ``simulate(seed=child)`` gives. Mode
    propositions are read with the commanded modes (the plan's), as without jumps.
    """
    rng = np.random.default_rng(seeds[0])
    r = roll_jumps(spec, plan, steps, switching, starts, rng, keep=keep)
    actions = plan.get_action()[:steps]
    belief = batch_monitor(formula, promised, r.means, r.covs, actions)
    state = batch_monitor(formula, promised, r.states, None, actions)
    results: list[dict[str, Any]] = []
    for i in range(starts.shape[0]):
        res: dict[str, Any] = {
            "belief_margin": float(belief["margin"][i]),
            "state_margin": float(state["margin"][i]),
            "belief_props": belief["props"][i].tolist(),
            "belief_preds": belief["preds"][i].tolist(),
            "state_props": state["props"][i].tolist(),
            "state_preds": state["preds"][i].tolist(),
            "executed_modes": r.executed[i].tolist(),
        }
        if i < keep:
            controls = r.controls[:, i].copy()
            res["trajectories"] = (
                ProbabilisticTSTrajectory(r.means[:, i].copy(), r.covs[:, i].copy(), actions, controls),
                RealTrajectory(r.states[:, i].copy(), r.observations[:, i].copy(), r.executed[i], controls),
            )
        results.append(res)
    return results
