"""The execution layer's façades (issue 22): ``simulate``, ``validate``, ``execute`` and
``start_check`` pack their keywords into the frozen ``ExecutorSpec`` / ``ReplanPolicy`` /
``ValidationSpec``; the spellings they replace still work, with a ``DeprecationWarning``; bad input
raises a package exception naming the argument.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError
from idstlpy.execution.validation_spec import VALIDATE_OPTIONS, ValidationSpec
from idstlpy.executor import ExecutorSpec

SOLVER = stl.SolverOptions.make(rrt_timeout=2, seed=0, guarantee="mlo")


def _problem() -> stl.Problem:
    """A noisy integrator that must reach a box and hold it (LP-exact: solves in milliseconds)."""
    x = stl.mk_variable(2, name="x")
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.08 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    target = stl.logical_and(
        stl.prob(x[0] >= 1.4) >= 0.9,
        stl.prob(x[0] <= 2.6) >= 0.9,
        stl.prob(x[1] >= -0.6) >= 0.9,
        stl.prob(x[1] <= 0.6) >= 0.9,
        name="target",
    )
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief(np.zeros(2), 0.05 * np.eye(2)),
        stl.eventually(0, 12, stl.always(0, 4, target)),
    )


@pytest.fixture(scope="module")
def case():
    problem = _problem()
    plan = problem.solve(options=SOLVER)
    assert plan is not None, problem.last_result
    real = stl.mk_switched_sys([stl.mk_lcs(A=np.eye(2), B=0.5 * np.eye(2))])
    return problem, plan, real, np.array([0.2, -0.1])


def _same_runs(a: stl.ValidationReport, b: stl.ValidationReport) -> None:
    assert a == b
    assert a.belief_margins == b.belief_margins and a.state_margins == b.state_margins
    assert a.replans == b.replans


# -- simulate ------------------------------------------------------------------------------------


def test_simulate_with_a_spec_is_simulate_with_its_keywords(case):
    problem, plan, real, x0 = case
    system, N = problem.switched_system, plan.num_of_steps
    kw = {"control_domain": problem.control_domain, "process_noise": "real"}
    by_keywords = stl.simulate(system, plan, N, x0, real, seed=3, **kw)
    spec = ExecutorSpec.make(system, real_system=real, **kw)
    by_spec = stl.simulate(system, plan, N, x0, None, seed=3, spec=spec)
    by_method = system.simulate(plan, N, x0, None, seed=3, spec=spec)  # the paper's spelling
    for (b1, r1), (b2, r2) in ((by_keywords, by_spec), (by_keywords, by_method)):
        assert np.array_equal(b1.get_mean(), b2.get_mean()) and np.array_equal(b1.get_cov(), b2.get_cov())
        assert np.array_equal(r1.get_state(), r2.get_state())
        assert np.array_equal(r1.get_observation(), r2.get_observation(), equal_nan=True)


@pytest.mark.parametrize(
    ("kw", "error", "name"),
    [
        ({"colour": "red"}, InvalidTypeError, "'colour'"),
        ({"spec": "an executor"}, InvalidTypeError, "spec"),
        ({"spec": "own", "control_domain": None}, InvalidArgumentError, "control_domain"),
        ({"spec": "own", "real": True}, InvalidArgumentError, "real_system"),
        ({"spec": "other"}, InvalidArgumentError, "spec"),
    ],
)
def test_simulate_bad_inputs_name_the_argument(case, kw, error, name):
    problem, plan, real, x0 = case
    system = problem.switched_system
    kw = dict(kw)
    if kw.get("spec") == "own":
        kw["spec"] = ExecutorSpec.make(system)
    elif kw.get("spec") == "other":
        kw["spec"] = ExecutorSpec.make(_problem().switched_system)
    real_system = real if kw.pop("real", False) else None
    with pytest.raises(error, match=name):
        stl.simulate(system, plan, 3, x0, real_system, seed=0, **kw)


# -- execute and start_check ---------------------------------------------------------------------


def test_execute_with_a_spec_is_execute_with_its_keywords(case):
    problem, plan, real, x0 = case
    policy = stl.ReplanPolicy(trigger="every", every=4, solver=SOLVER, adopt="always")
    by_keywords = stl.execute(problem, plan, real, x0, seed=5, policy=policy, process_noise="real")
    spec = ExecutorSpec.make(
        problem.switched_system, control_domain=problem.control_domain, real_system=real, process_noise="real"
    )
    by_spec = stl.execute(problem, plan, None, x0, seed=5, policy=policy, spec=spec)
    assert by_spec == by_keywords and by_spec.num_replans >= 1


@pytest.mark.parametrize(
    ("kw", "error", "name"),
    [
        ({"colour": "red"}, InvalidArgumentError, "colour"),
        ({"spec": 3}, InvalidTypeError, "spec"),
        ({"spec": "own", "clip_controls": False}, InvalidArgumentError, "clip_controls"),
        ({"spec": "own", "real": True}, InvalidArgumentError, "real_system"),
        ({"spec": "other"}, InvalidArgumentError, "spec"),
        ({"clip_controls": "yes"}, InvalidTypeError, "clip_controls"),
        ({"process_noise": "loud"}, InvalidArgumentError, "process_noise"),
    ],
)
def test_execute_bad_inputs_name_the_argument(case, kw, error, name):
    problem, plan, real, x0 = case
    kw = dict(kw)
    if kw.get("spec") == "own":
        kw["spec"] = ExecutorSpec.make(problem.switched_system)
    elif kw.get("spec") == "other":
        kw["spec"] = ExecutorSpec.make(_problem().switched_system)
    real_system = real if kw.pop("real", "spec" not in kw) else None
    with pytest.raises(error, match=name):
        stl.execute(problem, plan, real_system, x0, seed=0, **kw)


@pytest.mark.parametrize(
    ("kw", "error", "name"),
    [
        ({"colour": "red"}, InvalidTypeError, "'colour'"),
        ({"plant": lambda x, u, q, rng: x}, InvalidTypeError, "'plant'"),  # nothing moves before step 0
        ({"policy": "on_risk"}, InvalidTypeError, "policy"),
        ({"policy": stl.ReplanPolicy(), "risk": 0.5}, InvalidArgumentError, "policy"),
        ({"risk": 1.5}, InvalidArgumentError, "risk"),
        ({"resolves": -1}, InvalidArgumentError, "resolves"),
        ({"process_noise": "loud"}, InvalidArgumentError, "process_noise"),
    ],
)
def test_start_check_bad_inputs_name_the_argument(case, kw, error, name):
    problem, plan, _, _ = case
    with pytest.raises(error, match=name):
        stl.start_check(problem, plan, **kw)


def test_start_check_keywords_and_policy_agree(case):
    problem, plan, _, _ = case
    kw = {"risk": 1.0, "resolves": 1, "seed": 2, "options": SOLVER, "adopt": "always"}
    by_keywords = stl.start_check(problem, plan, **kw)
    policy = stl.ReplanPolicy(risk=1.0, solver=SOLVER, adopt="always")
    by_policy = stl.start_check(problem, plan, resolves=1, seed=2, policy=policy)
    assert by_keywords.predicted == by_policy.predicted
    assert by_keywords.initial_predicted == by_policy.initial_predicted
    assert [r.seed for r in by_keywords.replans] == [r.seed for r in by_policy.replans]


# -- validate ------------------------------------------------------------------------------------


def test_validate_replan_options_are_deprecated_for_a_policy(case):
    problem, plan, real, x0 = case
    args = (problem, plan, real, x0)
    kw = {"runs": 4, "seed": 4, "executor": "serial"}
    options = {"every": 3, "solver_options": {"rrt_timeout": 2, "guarantee": "mlo"}, "adopt": "always"}
    with pytest.warns(DeprecationWarning, match=r"validate\(replan=\.\.\., replan_options=\.\.\.\).*policy="):
        old = stl.validate(*args, **kw, replan="every", replan_options=options)
    policy = stl.ReplanPolicy.from_keywords("every", **options)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        new = stl.validate(*args, **kw, policy=policy)
        stl.validate(*args, **kw, replan=None, replan_options=None)  # explicit None: nothing to warn about
    _same_runs(old, new)
    assert len(new.replans) == 4 and sum(new.replans) >= 4


def test_the_deprecation_warning_points_at_the_callers_line(case):
    problem, plan, real, x0 = case
    with pytest.warns(DeprecationWarning) as caught:
        stl.validate(problem, plan, real, x0, runs=2, seed=0, executor="serial", replan="on_risk")
    assert caught[0].filename == __file__


@pytest.mark.parametrize(
    ("kw", "error", "name"),
    [
        ({"colour": "red"}, InvalidTypeError, "'colour'"),
        ({"policy": "every"}, InvalidTypeError, "policy"),
        ({"policy": stl.ReplanPolicy(), "replan": "every"}, InvalidArgumentError, "policy"),
        ({"policy": stl.ReplanPolicy(), "num_of_steps": 3}, InvalidArgumentError, "num_of_steps"),
        ({"progress": 3}, InvalidTypeError, "progress"),
        ({"problem_factory": "light_dark"}, InvalidTypeError, "problem_factory"),
        ({"max_workers": 0}, InvalidArgumentError, "max_workers"),
        ({"keep_trajectories": -1}, InvalidArgumentError, "keep_trajectories"),
        ({"batched": "yes"}, InvalidTypeError, "batched"),
        ({"execution_target": (0.9,)}, InvalidArgumentError, "execution_target"),
        ({"process_noise": "loud"}, InvalidArgumentError, "process_noise"),
        ({"lqr_gains": [[np.eye(3)]]}, DimensionError, "lqr gain"),
        ({"predict": True, "predict_options": {"runs": 3}}, InvalidArgumentError, "predict_options"),
        ({"predict": True, "plant": lambda x, u, q, rng: x, "real": False}, InvalidArgumentError, "predict"),
        ({"real_initial_state": "anywhere"}, InvalidArgumentError, "real_initial_state"),
        ({"real_initial_state": [0.0, 0.0, 0.0]}, DimensionError, "real_initial_state"),
        ({"runs": 0}, InvalidArgumentError, "runs"),
        ({"executor": "threads"}, InvalidArgumentError, "executor"),
    ],
)
def test_validate_bad_inputs_name_the_argument(case, kw, error, name):
    problem, plan, real, x0 = case
    kw = {"runs": 2, "seed": 0, "executor": "serial", **kw}
    real_system = real if kw.pop("real", True) else None
    x0 = kw.pop("real_initial_state", x0)
    with pytest.raises(error, match=name):
        stl.validate(problem, plan, real_system, x0, **kw)


def test_validation_spec_is_frozen_and_resolves_the_executor_once(case):
    problem, plan, real, x0 = case
    spec, dispatch = ValidationSpec.make(
        problem, plan, real, None, 5, 1, None, {"clip_controls": False, "keep_trajectories": 2}
    )
    assert spec.runs == 5 and spec.starts is not None and spec.starts.shape == (5, 2)
    assert spec.executor.control_domain is None and spec.keep_trajectories == 2
    assert dispatch.executor is None and dispatch.max_workers == 2
    with pytest.raises(AttributeError):
        spec.runs = 3  # type: ignore[misc]
    gains = spec.gains()
    assert len(gains) == problem.switched_system.num_modes
    assert all(not K.flags.writeable for Ks in gains for K in Ks)  # the spec's own, read-only
    assert {"policy", "clip_controls", "predict_options"} <= VALIDATE_OPTIONS


def test_the_typed_keywords_are_the_accepted_ones():
    """The ``Unpack[TypedDict]`` of each façade (what type checkers see) is what it accepts."""
    import inspect

    from idstlpy.execution.policy import POLICY_KEYWORDS
    from idstlpy.execution.precheck import START_CHECK_KEYWORDS, StartCheckOptions
    from idstlpy.execution.replanner import EXECUTOR_KEYWORDS, executor_spec
    from idstlpy.execution.replanning import ExecuteOptions
    from idstlpy.execution.simulation import EXECUTOR_OPTIONS, SimulateOptions
    from idstlpy.execution.validation_spec import REPLAN_OPTION_KEYS, ValidateOptions

    assert set(ExecuteOptions.__optional_keys__) == EXECUTOR_KEYWORDS | POLICY_KEYWORDS | {"replan"}
    assert set(StartCheckOptions.__optional_keys__) == START_CHECK_KEYWORDS | (EXECUTOR_KEYWORDS - {"plant"})
    assert START_CHECK_KEYWORDS <= POLICY_KEYWORDS and REPLAN_OPTION_KEYS == POLICY_KEYWORDS
    assert EXECUTOR_KEYWORDS <= set(ValidateOptions.__optional_keys__)
    make = set(inspect.signature(ExecutorSpec.make).parameters) - {"system", "real_system", "modes"}
    assert set(SimulateOptions.__optional_keys__) == set(EXECUTOR_OPTIONS) == make
    assert EXECUTOR_KEYWORDS == set(inspect.signature(executor_spec).parameters) - {"problem", "real_system"}
