"""Counterexample-guided synthesis: the proposer / teacher loop of the paper's Fig. 1.

1. LP pruning proves letters empty, pairs disjoint and steps impossible; these become clauses.
2. The BMC proposer finds the shortest depth with a satisfying claim assignment (iterative
   deepening on one incremental SAT solver) and proposes a candidate; a witness extraction keeps
   only the requirements that matter.
3. The LP teacher decides the candidate exactly when the covariance does not depend on the mean;
   otherwise it is a sound relaxation, and the belief-space sampler searches for real controls.
4. An LP infeasibility proof blocks its infeasible subset of requirements (with the modes that
   shaped it); a sampler time-out blocks exactly the failed candidate.
5. Every returned plan is re-rolled with the exact belief dynamics and passes the monitor.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..belief import rollout
from ..monitor import robustness
from .abstraction import Abstraction
from .bmc import BMCEncoder
from .milp import solve_milp
from .plan import DiscretePlan, extract_witness
from .problem import SolveResult, SolverOptions, SolveStats
from .sampler import BeliefSampler
from .teacher import solve_plan_lp

__all__ = ["synthesize"]

logger = logging.getLogger(__name__)

_LAZY_CANDIDATES = 10
"""Candidates the lazy loop may try before an LP-exact problem goes to the eager MILP."""


class _Clock:
    def __init__(self, stats: SolveStats, field: str) -> None:
        self.stats, self.field = stats, field

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        setattr(self.stats, self.field, getattr(self.stats, self.field) + time.perf_counter() - self.t0)


def synthesize(problem, options: SolverOptions) -> SolveResult:
    """Run the CEGIS loop on ``problem`` (see the module docstring)."""
    t0 = time.perf_counter()
    stats = SolveStats()
    budget = options.time_limit if options.time_limit is not None else 10.0 * options.rrt_timeout
    deadline = t0 + budget
    rng = np.random.default_rng(options.seed)
    system = problem.switched_system
    formula = problem.stl_formula
    init = problem.initial_state

    def done(status: str, reason: str, traj=None, margin: float = float("nan")) -> SolveResult:
        stats.time_total = time.perf_counter() - t0
        logger.info("solve: %s (%s) in %.3f s", status, reason, stats.time_total)
        return SolveResult(status, traj, reason, margin, stats)  # type: ignore[arg-type]

    abstraction = Abstraction(formula, system.n)
    with _Clock(stats, "time_bmc"):
        enc = BMCEncoder(formula, abstraction.atoms, system.num_modes)
    try:
        with _Clock(stats, "time_lp"):
            report = abstraction.prune(system, problem.control_domain, init.mean, init.cov)
        _add_pruning(enc, report, stats)
        H = enc.H
        if abstraction.num_atoms:
            enc.set_phases([int(v) for v in enc.p.ravel()])
        with _Clock(stats, "time_bmc"):
            sat = enc.solve()
            if sat:
                for i in report.initial_false:
                    enc.add_clause([-int(enc.p[i, 0])])
                sat_init = enc.solve()
        if not sat:
            return done(
                "infeasible",
                "the formula is unsatisfiable over its propositions (its logic, or empty / disjoint regions)",
            )
        if not sat_init:
            names = ", ".join(abstraction.names()[i] for i in report.initial_false)
            return done(
                "infeasible",
                f"the initial belief does not satisfy what the formula requires at step 0 ({names})",
            )
        with _Clock(stats, "time_bmc"):
            depth = _shortest_depth(enc, H)
        sampler: BeliefSampler | None = None
        eager = system.num_modes == 1 and not system.system_modes[0].has_state_dependent_noise
        while True:
            if time.perf_counter() > deadline:
                return done("budget_exhausted", f"time limit of {budget:.3g} s reached")
            if options.max_candidates is not None and stats.candidates >= options.max_candidates:
                return done("budget_exhausted", f"{options.max_candidates} candidates tried")
            if eager and stats.candidates >= _LAZY_CANDIDATES:
                return _eager(problem, enc, abstraction, deadline, stats, done)
            stats.bmc_depth = max(stats.bmc_depth, depth)
            with _Clock(stats, "time_bmc"):
                sat = enc.solve(depth)
            if not sat:
                if depth >= H:
                    return done(
                        "infeasible",
                        "every discrete plan up to the formula's horizon was refuted by the dynamics",
                    )
                depth = min(H, depth + max(1, depth // 4))
                logger.info("BMC: deepening to %d steps", depth)
                continue
            claims, modes, length = enc.model_claims()
            witness = extract_witness(formula, claims[:, :length], abstraction.index, prefer_late=True)
            if witness is None:  # cannot happen for a model of the encoding; block and go on
                logger.warning("BMC model does not satisfy the formula; blocking it")
                enc.add_clause([-int(v) for v in enc.p[:, :length][claims[:, :length]]] or [-enc.T])
                continue
            required, L = witness
            plan = DiscretePlan(required[:, :L], modes[:L].copy(), L)
            stats.candidates += 1
            with _Clock(stats, "time_lp"):
                margin = _execution_margin(system, init, abstraction, plan)
                lp = solve_plan_lp(
                    system, problem.control_domain, init.mean, init.cov, abstraction, plan, margin
                )
            stats.lp_calls += 1
            if lp.means is not None and abstraction.num_atoms:
                _guide_phases(enc, abstraction, lp, plan)
            if not lp.feasible:
                _block(enc, plan, lp.conflict, system.num_modes)
                stats.counterexamples += 1
                logger.debug(
                    "candidate %d: LP conflict on %d requirements",
                    stats.candidates,
                    len(lp.conflict),
                )
                continue
            actions = plan.modes[1:L].astype(int)
            if lp.exact:
                result = _verify(problem, actions, lp.controls)
                if result is not None:
                    traj, margin = result
                    return done(
                        "found",
                        "the plan LP is feasible and the plan passes the monitor",
                        traj,
                        margin,
                    )
                _block(enc, plan, plan.requirements(), system.num_modes)
                stats.counterexamples += 1
                continue
            # State-dependent noise: the LP was a relaxation; search belief space for real controls.
            if sampler is None:
                sampler = BeliefSampler(problem, abstraction, enc, options, rng)
            stop = min(deadline, time.perf_counter() + options.rrt_timeout)
            sat_before = enc.sat_calls
            with _Clock(stats, "time_sampling"):
                out = sampler.run(plan, stop)
            stats.nodes += out.nodes
            stats.sat_calls += enc.sat_calls - sat_before
            if out.actions is not None:
                with _Clock(stats, "time_sampling"):
                    actions, controls = sampler.shortcut(out.actions, out.controls)
                result = _verify(problem, actions, controls)
                if result is not None:
                    with _Clock(stats, "time_lp"):
                        traj, margin = _polish(problem, abstraction, *result, stats)
                    return done(
                        "found",
                        "the belief-space sampler met the plan and the monitor agrees",
                        traj,
                        margin,
                    )
            _block(enc, plan, plan.requirements(), system.num_modes)
            stats.counterexamples += 1
            logger.info(
                "candidate %d: sampler time-out after %d nodes; blocked",
                stats.candidates,
                out.nodes,
            )
    finally:
        stats.sat_calls = max(stats.sat_calls, enc.sat_calls)
        enc.close()


def _add_pruning(enc: BMCEncoder, report, stats: SolveStats) -> None:
    H = enc.H
    for i in report.empty_atoms:
        for k in range(H + 1):
            enc.add_clause([-int(enc.p[i, k])])
    for i, j in report.disjoint_pairs:
        for k in range(H + 1):
            enc.add_clause([-int(enc.p[i, k]), -int(enc.p[j, k])])
    for i, j, q in report.impossible_steps:
        for k in range(H):
            clause = [-int(enc.p[i, k]), -int(enc.p[j, k + 1])]
            if q >= 0:
                clause.append(-int(enc.m[q, k + 1]))
            enc.add_clause(clause)
    stats.pruned_letters = len(report.empty_atoms) + len(report.disjoint_pairs) + len(report.initial_false)
    stats.pruned_steps = len(report.impossible_steps)


def _eager(problem, enc: BMCEncoder, abstraction: Abstraction, deadline: float, stats: SolveStats, done):
    """Hand an LP-exact, single-mode problem to HiGHS as one MILP (see :mod:`.milp`).

    The MILP chooses the discrete plan; its continuous part is re-solved by the plan LP (with the
    execution margin) when the MILP's own controls miss the exact check by solver tolerances.
    """
    logger.info("%d candidates refuted: switching to the eager MILP", stats.candidates)
    init, system = problem.initial_state, problem.switched_system
    with _Clock(stats, "time_lp"):
        status, actions, controls, claims = solve_milp(
            enc,
            abstraction,
            system,
            problem.control_domain,
            init.mean,
            init.cov,
            deadline - time.perf_counter(),
        )
    stats.lp_calls += 1
    if status == "infeasible":
        return done("infeasible", "the eager MILP proved that no plan exists within the horizon")
    if status != "found":
        return done("budget_exhausted", "time limit reached in the eager MILP")
    witness = extract_witness(problem.stl_formula, claims, abstraction.index, prefer_late=True)
    if witness is not None:
        required, L = witness
        plan = DiscretePlan(required[:, :L], np.zeros(L, dtype=int), L)
        with _Clock(stats, "time_lp"):
            lp = solve_plan_lp(
                system,
                problem.control_domain,
                init.mean,
                init.cov,
                abstraction,
                plan,
                _execution_margin(system, init, abstraction, plan),
            )
        stats.lp_calls += 1
        if lp.feasible:
            actions, controls = np.zeros(L - 1, dtype=int), lp.controls
    result = _verify(problem, actions, controls)
    if result is not None:
        traj, margin = result
        return done(
            "found", "the eager MILP chose the plan, the LP timed it, the monitor agrees", traj, margin
        )
    return done("budget_exhausted", "the MILP's plan failed the monitor's exact re-check")


def _shortest_depth(enc: BMCEncoder, H: int) -> int:
    """Smallest bound with a satisfying claim assignment (binary search; SAT is monotone in it)."""
    lo, hi = 0, H
    while lo < hi:
        mid = (lo + hi) // 2
        if enc.solve(mid):
            hi = mid
        else:
            lo = mid + 1
    return lo


def _block(enc: BMCEncoder, plan: DiscretePlan, conflict, num_modes: int) -> None:
    """Forbid the conflicting requirements together (with the modes that led to them)."""
    clause = [-int(enc.p[i, k]) for (k, i) in conflict]
    if num_modes > 1 and conflict:
        last = max(k for k, _ in conflict)
        clause += [-int(enc.m[int(plan.modes[j]), j]) for j in range(1, last + 1)]
    if not clause:
        clause = [-enc.T]  # nothing left to try
    enc.add_clause(clause)


def _guide_phases(enc: BMCEncoder, abstraction: Abstraction, lp, plan: DiscretePlan) -> None:
    """Prefer, in the next SAT search, the labels the LP's trajectory actually has."""
    K = lp.means.shape[0] - 1
    phases = []
    for k in range(1, K + 1):
        truth = abstraction.truth(lp.means[k], lp.covs[k], int(plan.modes[k]))
        phases.extend(int(v) if t else -int(v) for v, t in zip(enc.p[:, k], truth, strict=True))
    phases.extend(int(v) for v in enc.p[:, K + 1 :].ravel())
    enc.set_phases(phases)


def _execution_margin(system, init, abstraction: Abstraction, plan: DiscretePlan) -> float:
    """Room to leave inside required regions when the plan will meet noise (0 when it will not).

    Half the Chebyshev radius of the smallest bounded required region (1 state unit when every
    required region is unbounded).
    """
    noisy = np.any(init.cov != 0) or any(
        np.any(mode.process_cov != 0) or mode.p > 0 for mode in system.system_modes
    )
    if not noisy:
        return 0.0
    radii = []
    for i in np.nonzero(plan.required.any(axis=1))[0]:
        radius = abstraction.radius(int(i))
        if np.isfinite(radius) and radius < 1e5:
            radii.append(radius)
    return 0.5 * min(radii) if radii else 1.0


def _polish(problem, abstraction: Abstraction, traj, margin: float, stats: SolveStats, rounds: int = 4):
    """Move a sampler's plan away from the boundaries it grazes, keeping its modes.

    The sampler stops at the first belief that meets the plan, often a hair inside a required
    region, and such a plan breaks under execution noise. Each round freezes the trajectory's
    exact covariances, asks the plan LP for the controls that maximise the smallest slack of the
    requirements the trajectory meets (means may move by at most ``trust``), re-rolls the exact
    belief dynamics and keeps the result only if the monitor's margin grew; ``trust`` halves
    after a round that did not help.
    """
    init, system = problem.initial_state, problem.switched_system
    trust = np.inf  # set from the first round's margin target
    for _ in range(rounds):
        actions = traj.get_action()
        modes = np.concatenate([[-1], actions]).astype(int)
        means, covs = traj.get_mean(), traj.get_cov()
        labels = [abstraction.truth(mu, cov, int(q)) for mu, cov, q in zip(means, covs, modes, strict=True)]
        truth = np.stack(labels, axis=1)
        witness = extract_witness(problem.stl_formula, truth, abstraction.index, prefer_late=False)
        if witness is None:
            break
        required, L = witness
        plan = DiscretePlan(required[:, :L], modes[:L], L)
        target = _execution_margin(system, init, abstraction, plan)
        if target <= margin:
            break
        trust = min(trust, 2.0 * target)
        lp = solve_plan_lp(
            system, problem.control_domain, init.mean, init.cov, abstraction, plan, target,
            covs=covs[:L], anchor=means[:L], trust=trust,
        )
        stats.lp_calls += 1
        if lp.feasible:
            moved = rollout(system, init, actions[: L - 1], lp.controls)
            moved_margin = robustness(moved, problem.stl_formula)
            if moved_margin > margin:
                logger.debug("polish: margin %.3g -> %.3g (trust %.3g)", margin, moved_margin, trust)
                traj, margin = moved, moved_margin
                continue
        trust *= 0.5
    return traj, margin


def _verify(problem, actions: np.ndarray, controls: np.ndarray):
    traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
    margin = robustness(traj, problem.stl_formula)
    if margin >= 0:
        return traj, margin
    logger.warning("candidate failed the monitor re-check (margin %.3g)", margin)
    return None
