"""Predict, before executing, what the executor will do with a plan (the linear-Gaussian closed loop).

This module sits below the synthesis layer (the planner's default guarantee asks it whether a
plan meets its execution target); :mod:`idstlpy.execution.prediction` re-exports it.

:func:`~idstlpy.execution.simulate.simulate` tracks a plan with a Kalman filter and
receding-horizon LQR. Around the plan (modes ``q_k``, means ``m_k``, inputs ``v_k``) that loop is
linear, as in LQG-MP (van den Berg, Abbeel, Goldberg, 2011). With ``delta_k = x_k - m_k`` the
true state's deviation and ``eta_k = mean_k - m_k`` the executed belief mean's deviation, one step
of mode ``q`` (model ``A, B, C``, real ``A_r, B_r``, tracking gain ``K``, Kalman gain ``L``) is::

    u_k         = v_k - K eta_k
    delta_{k+1} = A_r delta_k - B_r K eta_k + d_k + W w_k
    eta_{k+1}   = L C A_r delta_k + ((I - L C)(A - B K) - L C B_r K) eta_k
                  - (I - L C) r_k + L C d_k + L C W w_k + L n(x_{k+1}) v_{k+1}

with ``d_k = A_r m_k + B_r v_k - m_{k+1}`` (model mismatch) and ``r_k = m_{k+1} - A m_k - B v_k``
(zero for a plan made by the MLO roll-out). The joint state ``z = (delta, eta)`` (``2n``) is a
linear Gauss-Markov process: its mean starts at ``(x_0 - m_0, mean_0 - m_0)`` (the paper's true
start [0.5, 2.75] against the belief mean [0, 2.5]) and its ``2n x 2n`` covariance is propagated
exactly, ``S_{k+1} = F_k S_k F_k' + Q_k``.

What is exact and what is approximated
--------------------------------------
- **Constant sensor noise, inputs never clipped**: the filter's gains and covariances do not
  depend on the observations, so the prediction is the exact distribution of the execution.
- **Clipped inputs.** ``simulate`` projects ``v_k - K eta_k`` on the control domain: a box
  per coordinate (a clip), any other polytope by its Euclidean projection
  (:func:`idstlpy.tracking.control_projector`, one function for the executor and the
  prediction). Under the Gaussian closure a box's clip is replaced by its statistical
  linearisation: exact mean of the clipped input, exact cross-covariance with the loop
  (Stein's lemma: the gain becomes ``diag(P[inside]) K``), its remaining variance as
  independent noise. A projection on another polytope has no such closed form: the Gaussian
  closure's moments are the unprojected loop's, its point estimates are sampled through the
  projection itself, and its lower bounds are the unprojected loop's minus the probability
  that the input leaves the domain at some step (both loops agree on every run where it does
  not: sound). The default ``"auto"`` closure takes particles, which apply the projection to
  every sample, as soon as the input leaves a domain (box or not) with probability above 1%.
  :attr:`ClosedLoopPrediction.clip_probability` reports, per step, an upper bound on the
  probability that the input is clipped or projected.
- **State-dependent sensor noise** ``R(x) = n(x) n(x)'`` is linearised around the plan, in three
  places. (1) The observation noise acting on the loop is ``n(x_{k+1}) v`` at the *true* state:
  ``sensor_noise="expected"`` (default) uses ``E[R(x_{k+1})]`` over the predicted true state
  (Gauss-Hermite cubature; this makes the loop's first two moments right given the gains),
  ``"mean"`` uses ``R`` at the predicted true-state mean and ``"plan"`` at the planned mean
  ``m_{k+1}``. (2) The filter evaluates ``R`` at its own, random, predicted mean: the Kalman gains
  and the filter covariance ``filter_cov`` are computed at the predicted mean of that point
  (``"plan"``: at the plan's, which reproduces the plan's covariances). (3) With
  ``filter_sensitivity=True`` (default) the first-order variation of the filter covariance with
  the filter's mean path, ``dP_{k+1} = Phi dP_k Phi' + L dR L'`` (``Phi = (I - L C) A``; the
  Joseph form is stationary in the gain), is carried as ``n^2`` extra coordinates of the state,
  so that the executed belief's chance constraints, whose ``sqrt(h' P_k h)`` term moves with the
  observations, are linear in one Gaussian vector. The loop is then only approximately Gaussian;
  ``benchmarks/closed_loop.py`` and ``tests/test_prediction.py`` measure the error against Monte
  Carlo.
- **The particle closure** (``closure="particles"``, chosen by the default ``"auto"`` under a
  state-dependent sensor or when the input is clipped with probability above 1%). Both
  non-linearities above make the loop non-Gaussian in ways no Gaussian can follow: a plan riding
  an input bound makes the clipped loop a rectifier (lags are not corrected and accumulate: the
  true state's spread was 3x the linearisation's on the sensor-switching plan), and a
  state-dependent sensor skews the true state toward the dark. Samples of ``z`` are then pushed
  through the loop with the clip or projection itself (``simulate``'s), the process
  noise of ``simulate``, each sample drawing the sensor's noise from the user's noise function
  at its own true state and, with ``filter_sensitivity``, running its own filter (``R`` at its
  own predicted mean, as ``simulate``'s filter evaluates it, its own covariance, whose deviation
  from the nominal one is the ``dP`` coordinates). The noise function is called on the samples
  (once for the batch when it takes one, else once per sample), except where the noise factor's
  quadratic interpolant over the predicted true state reproduces it at the step's extreme
  samples and 64 others (:class:`~idstlpy.loop_samples.SensorDraw`: a factor quadratic in each
  coordinate, the interpolant is then exact and 3 calls per direction replace one per sample).
  A step sensor (light-dark spot) is thereby sampled as executed: the interpolant, which cannot
  follow a step, had over-predicted the issue's 1-D problem's true-state success by 2.4 points
  (97.8 against 95.4 measured; now 95.4 / 95.6 against 95.5 +- 0.3, 20000 samples against 4000
  executions). The moments are the samples' and ``F, g, Q`` their statistical linear regression;
  the point estimates below are sampled from the same non-linear loop, so for the per-sample
  law they are unbiased estimates of ``simulate``'s rates (from prior-drawn starts) up to their
  sampling error. What remains approximate: the interpolant's check is a test (a region of the
  state where the interpolant is wrong and that fewer than a few percent of the samples visit
  can go unnoticed), and the Gaussian marginals behind the per-step probabilities and the
  analytic bound (which is then capped by the sampled one).

From the (augmented) Gaussian, per chance constraint ``P[h'x + c <= 0] >= 1 - eps`` of every
atomic proposition at every step:

- the probability that the **executed belief** satisfies it,
  ``P[h' mean_k + c + Phi^-1(1 - eps) sqrt(h' P_k h) <= 0]`` (``P_k`` the filter covariance;
  :mod:`idstlpy.chance` computes the term);
- the probability that the **true state** satisfies its deterministic reading ``h'x_k + c <= 0``.

A *lower bound* on the probability that the whole formula holds (executed belief, true state):
one minus Hunter's tree bound on the union of the failures of the events a witness of the
formula needs (per constraint, its steps chained in time, with exact bivariate normal
probabilities); the witness is the plan's own (:func:`idstlpy.label_semantics.extract_witness`,
latest and earliest until-steps) or the one a dynamic programme on the predicted failure
probabilities finds, whichever bound is smallest. It is sound for the Gaussian model (so exactly
sound in the exact case above). Point estimates of the rates
:func:`~idstlpy.execution.validate.validate` measures (a constraint broken at some promised
step, the formula's success) come from sampling the Gaussian model (no filter, no simulation).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Unpack

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int
from ..closed_loop import ClosedLoopMoments, prob_le, propagate
from ..dynamical_system import LCS, SwitchedSystem
from ..formulas import STLAtomicProposition, STLFormula
from ..semantics import atom_margins
from ..trajectory import ProbabilisticTSTrajectory
from .blas import single_blas_thread
from .model_sampling import clopper_pearson_lower, sample_rates
from .predict_args import (
    EXECUTOR_DEFAULTS,
    LoopSettings,
    PredictOptions,
    SensorNoise,
    check_closure,
    executor_parts,
    plan_steps,
    resolve,
    start_of,
    with_defaults,
)
from .predicted import ClosedLoopPrediction, ConstraintPrediction
from .spec import ExecutorSpec
from .success_bound import Faces, bivariate_normal_cdf, mode_truth, stack_faces, success_bound

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = [
    "ClosedLoopPrediction",
    "ConstraintPrediction",
    "PredictOptions",
    "predict_closed_loop",
    "bivariate_normal_cdf",
    "SensorNoise",
]

logger = logging.getLogger(__name__)

# --------------------------------------------------------------------------------------------
# The prediction


def _moments(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    N: int,
    setup: LoopSettings,
    start: tuple[Any, ...],
) -> tuple[ClosedLoopMoments, dict[str, Any]]:
    """The closed loop's moments and the prediction's fields that do not need a formula."""
    z0, S0, P0 = start
    s = setup
    loop = propagate(
        system, plan, N, s.real_modes, s.gains, s.process_noise, z0, S0, P0, s.sensor_noise, s.domain,
        s.filter_sensitivity, s.closure, s.particles,
    )  # fmt: skip
    if loop.unmodelled_projection and N:
        logger.debug(
            "predict_closed_loop: Gaussian moments without the projection on the control domain "
            "(taken with probability at most %.3g over the plan); the rates are sampled through it",
            min(1.0, float(loop.clip.sum())),
        )
    base: dict[str, Any] = {
        "num_of_steps": N,
        "sensor_noise": s.sensor_noise,
        "plan_means": plan.get_mean()[: N + 1].copy(),
        "filter_cov": loop.P,
        "augmented_mean": loop.mean,
        "augmented_cov": loop.cov,
        "transitions": loop.F,
        "offsets": loop.g,
        "noise_covs": loop.Q,
        "tracking_gains": loop.K,
        "kalman_gains": tuple(loop.L),
        "clip_probability": loop.clip,
        "closure": loop.closure,
    }
    return loop, base


def _plan_truth(aps: list[STLAtomicProposition], plan: ProbabilisticTSTrajectory, L: int) -> np.ndarray:
    """The plan's promise per proposition and step (validate's mask; the plan witness's truth)."""
    truth = np.zeros((len(aps), L), dtype=bool)
    for i, ap in enumerate(aps):
        margins = atom_margins(ap, plan.get_mean(), plan.get_cov(), plan.get_action())
        upto = min(L, margins.shape[0])
        truth[i, :upto] = margins[:upto] >= 0.0
    return truth


def _constraints(
    aps: list[STLAtomicProposition],
    names: list[str],
    faces: Faces,
    per_step: dict[str, np.ndarray],
    plan_truth: np.ndarray,
    viol: dict[str, np.ndarray],
) -> tuple[ConstraintPrediction, ...]:
    """One :class:`ConstraintPrediction` per face of every proposition, in validate's order."""
    out = []
    j = 0
    for i, ap in enumerate(aps):
        for pred in ap.predicates:
            out.append(
                ConstraintPrediction(
                    name=f"{names[i]}: {pred}",
                    proposition=names[i],
                    h=faces.H[j].copy(),
                    c=float(faces.c[j]),
                    eps=float(pred.eps),
                    belief_probability=per_step["belief"][:, j].copy(),
                    state_probability=per_step["state"][:, j].copy(),
                    promised=plan_truth[i].copy(),
                    belief_violation=float(viol["belief"][j]),
                    state_violation=float(viol["state"][j]),
                )
            )
            j += 1
    return tuple(out)


def _with_formula(
    loop: ClosedLoopMoments,
    base: dict[str, Any],
    formula: STLFormula,
    plan: ProbabilisticTSTrajectory,
    actions: np.ndarray,
    samples: int,
    seed: int | np.random.SeedSequence | None,
) -> ClosedLoopPrediction:
    """The prediction of a formula's chance constraints and success over the loop's moments."""
    N = base["num_of_steps"]
    L, n = N + 1, plan.n
    aps = [ap for ap in formula.atomic_propositions() if not ap.is_false and not ap.is_true]
    names = [ap.name or f"ap{i}" for i, ap in enumerate(aps)]
    faces = stack_faces(aps, loop, base["plan_means"], n)
    mode_ok = mode_truth(aps, actions, L)
    plan_truth = _plan_truth(aps, plan, L)
    per_step = {r: prob_le(faces.mu[r], faces.sd[r]) for r in ("state", "belief")}  # (L, F)
    nF = faces.H.shape[0]
    viol = {"state": np.full(nF, np.nan), "belief": np.full(nF, np.nan)}
    prop_violation = {nm: {"belief": float("nan"), "state": float("nan")} for nm in names}
    estimate = {"state": float("nan"), "belief": float("nan")}
    if samples:
        viol, prop_rates, estimate, sampled = sample_rates(
            loop, faces, samples, seed, formula, aps, mode_ok, plan_truth
        )
        if loop.closure == "particles" or loop.unmodelled_projection:  # the loop's own, sampled
            per_step = {r: sampled[r] for r in ("state", "belief")}
        prop_violation = {
            nm: {r: float(prop_rates[r][i]) for r in ("belief", "state")} for i, nm in enumerate(names)
        }
    state_bound, witness = success_bound(formula, aps, faces, mode_ok, plan_truth, "state", loop)
    belief_bound, _ = success_bound(formula, aps, faces, mode_ok, plan_truth, "belief", loop)
    logger.debug(
        "predict_closed_loop: %d steps, success bound state %.4g belief %.4g, "
        "estimate state %.4g belief %.4g",
        N,
        state_bound,
        belief_bound,
        estimate["state"],
        estimate["belief"],
    )
    if loop.unmodelled_projection:
        # The bounds are the unprojected Gaussian loop's. Both loops driven by the same noise
        # agree on every run where no input leaves the domain, so the executed loop succeeds with
        # probability at least the bound minus the probability that an input leaves the domain
        # at some step, at most the sum over steps of ``clip`` (each step's union bound over the
        # faces, exact Gaussian probabilities of the unprojected loop).
        leave = min(1.0, float(loop.clip.sum()))
        state_bound = max(0.0, state_bound - leave)
        belief_bound = max(0.0, belief_bound - leave)
    sampled_bound = {r: clopper_pearson_lower(estimate[r], samples) for r in ("belief", "state")}
    if loop.closure == "particles" and samples:
        belief_bound = min(belief_bound, sampled_bound["belief"])
        state_bound = min(state_bound, sampled_bound["state"])
    return ClosedLoopPrediction(
        **base,
        constraints=_constraints(aps, names, faces, per_step, plan_truth, viol),
        propositions=tuple(names),
        proposition_violation=prop_violation,
        belief_success_bound=float(belief_bound),
        state_success_bound=float(state_bound),
        belief_success_estimate=estimate["belief"],
        state_success_estimate=estimate["state"],
        belief_success_sampled_bound=sampled_bound["belief"],
        state_success_sampled_bound=sampled_bound["state"],
        samples=samples,
        witness=tuple((names[i], int(k)) for i, k in witness),
    )


# --------------------------------------------------------------------------------------------
# Public entry point


def predict_closed_loop(
    problem_or_system: Problem | SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None = None,
    real_initial_state: ArrayLike | None = None,
    *,
    formula: STLFormula | None = None,
    num_of_steps: int | None = None,
    samples: int = 4000,
    seed: int | np.random.SeedSequence | None = 0,
    executor: ExecutorSpec | None = None,
    **options: Unpack[PredictOptions],
) -> ClosedLoopPrediction:
    """Predict the execution of a plan by :func:`~idstlpy.execution.simulate.simulate`.

    Takes the execution options of ``simulate`` / ``validate`` and returns the distribution of
    the true state and of the executed belief at every step, the predicted probability of every
    chance constraint at every step, and a sound lower bound and a point estimate for the formula
    (module notes: exact for constant sensor noise without clipping; clipping on a box and
    state-dependent sensor noise are linearised around the plan).

    Parameters
    ----------
    problem_or_system : Problem or SwitchedSystem
        The planning model (and, for a Problem, the formula and the control domain).
    plan : ProbabilisticTSTrajectory
        The plan, ``N`` steps, state dimension ``n``, input dimension ``m``.
    real_system : SwitchedSystem or LCS, optional
        The system moving the true state (one mode per planning mode, or one for all); default
        the planning model itself.
    real_initial_state : array_like, shape (n,), optional
        True initial state (default the plan's initial mean).
    formula : STLFormula, optional
        Overrides the problem's formula; without any, only the moments are predicted.
    num_of_steps : int, optional
        Steps executed, ``0 <= num_of_steps <= N`` (default ``N``).
    samples : int
        Samples of the Gaussian model for the point estimates (0: none, the estimates are NaN).
    seed : int or SeedSequence, optional
        Seed of those samples (default 0: deterministic).
    executor : ExecutorSpec, optional
        What runs the plan, resolved once (:meth:`idstlpy.executor.ExecutorSpec.make`: its
        control domain, process-noise reading, tracking gains and linear real system); exclusive
        with ``real_system``, ``control_domain``, ``process_noise``, ``lqr_gains`` and
        ``default_lqr``. Its system must be the planning model.
    **options
        The executor's settings as keywords, and the closure's (:class:`PredictOptions`):

        - ``control_domain`` (Polytope, None or "problem"): the polytope (shape ``m``) the
          corrected input is projected on: ``"problem"`` (default) the problem's, as
          ``validate(clip_controls=True)``; None: no projection, as ``simulate`` without
          ``control_domain``.
        - ``process_noise`` ({"auto", "model", "real", "none"}): as in ``simulate``.
        - ``lqr_gains``, ``default_lqr`` (optional): as in ``simulate`` (per-mode gains (m, n);
          weights for modes without gains).
        - ``initial_belief`` (GaussianBelief, optional): the filter's prior (default the plan's
          first belief).
        - ``real_initial_cov`` (array_like, shape (n, n), optional): covariance of a random true
          initial state (default 0: ``simulate``'s fixed start).
        - ``sensor_noise`` ({"expected", "mean", "plan"}): linearisation of state-dependent
          sensor noise (module notes); no effect on constant noise.
        - ``filter_sensitivity`` (bool, default True): carry the first-order variation of the
          filter covariance with the filter's mean path (state-dependent noise only).
        - ``closure`` ({"auto", "gaussian", "particles"}): how the loop's non-linearities are
          modelled (:func:`idstlpy.closed_loop.propagate`): ``"gaussian"``: the clip of the
          corrected input on a box by its statistical linearisation and a state-dependent sensor
          linearised (``sensor_noise``), the loop kept Gaussian (on a non-box domain the moments
          leave the projection out; the estimates are sampled through it and the bounds
          discounted by the probability that it acts, module notes); ``"particles"``:
          ``particles`` samples (seed 0, deterministic) pushed through the clip or projection
          itself, each drawing the sensor's noise at its own true state and running its own
          filter; the moments are theirs and the point estimates are sampled from the same
          loop; ``"auto"`` (default): particles under a state-dependent sensor or when the
          input leaves the control domain with probability above 1% at some step.
        - ``particles`` (int, default 4000): samples of the particle closure.

    Returns
    -------
    ClosedLoopPrediction

    Raises
    ------
    InvalidArgumentError
        When the plan is None, an option is invalid or the predicted loop diverges.
    DimensionError
        When dimensions of the plan, the model, the domain and the real system disagree.
    InvalidTypeError
        When an argument has the wrong type, or a keyword is unknown.

    Notes
    -----
    The samples and particles are pushed through the loop with every loaded OpenBLAS on one
    thread (:mod:`idstlpy.executor.blas`): their products are too small to gain from threads,
    and threads that wait for each other on a busy machine made the prediction up to 10x slower.
    """
    opts = with_defaults(options)
    system, formula, domain = resolve(problem_or_system, formula, opts["control_domain"])
    N, actions = plan_steps(system, plan, num_of_steps)
    keywords = {k: opts[k] for k in EXECUTOR_DEFAULTS if k != "real_system"} | {"real_system": real_system}
    real_modes, gains, noise, domain = executor_parts(system, actions, executor, keywords, domain, plan)
    samples = as_int(samples, "samples", minimum=0)
    sensor_noise, sensitivity, closure = opts["sensor_noise"], opts["filter_sensitivity"], opts["closure"]
    setup = LoopSettings(
        real_modes, gains, noise, domain, sensor_noise, sensitivity, closure,
        check_closure(sensor_noise, sensitivity, closure, opts["particles"]),
    )  # fmt: skip
    start = start_of(plan, system.n, real_initial_state, opts["initial_belief"], opts["real_initial_cov"])
    with single_blas_thread():
        loop, base = _moments(system, plan, N, setup, start)
        if formula is None:
            return ClosedLoopPrediction(**base)
        return _with_formula(loop, base, formula, plan, actions, samples, seed)
