"""``validate(..., predict=True)``: the prediction of exactly the executed loop, next to Monte Carlo.

- fields: the report's prediction is :func:`predict_closed_loop` under validate's own execution
  options (gains, projection, process noise, real system, start, steps), and the comparison,
  summary and ``as_dict`` put every predicted rate next to the measured one;
- agreement: with constant sensor noise and unclipped inputs the prediction is the distribution
  of the execution, so predicted and measured rates agree within a sound statistical tolerance
  (and a wrong prediction does not);
- the execution figure draws the predicted true-state ellipses; the CLI's ``--predict``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.cli import EXIT_OK, main
from idstlpy.errors import InvalidArgumentError, InvalidTypeError, ProblemFileError
from idstlpy.execution.prediction import ClosedLoopPrediction, predict_closed_loop

RUNS = 300
SAMPLES = 4000
X0 = np.array([0.3, -0.15])


def _hold_problem():
    """2-D random walk held near the origin under constant sensor noise; the plan is the zero input.

    Chosen so that the promise is broken often enough to measure (about 15% of executed beliefs,
    a few % of true states, per constraint): a test of agreement on rates of 0 would be empty.
    """
    x, u = stl.mk_variable(2), stl.mk_variable(2, name="u")
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=0.1 * np.eye(2), C=np.eye(2), V=0.3 * np.eye(2))]
    )
    near = stl.logical_and(stl.prob(x[0] <= 0.6) >= 0.9, stl.prob(x[1] >= -0.6) >= 0.9, name="near")
    domain = stl.logical_and(u[0] >= -5, u[0] <= 5, u[1] >= -5, u[1] <= 5).region
    problem = stl.Problem(system, domain, stl.to_belief([0, 0], 0.1 * np.eye(2)), stl.always(0, 15, near))
    plan = stl.rollout(system, problem.initial_state, np.zeros(15, dtype=int), np.zeros((15, 2)))
    assert stl.satisfies(plan, problem.stl_formula)
    return problem, plan


@pytest.fixture(scope="module")
def hold():
    problem, plan = _hold_problem()
    report = stl.validate(
        problem,
        plan,
        problem.switched_system,
        X0,
        runs=RUNS,
        seed=3,
        executor="serial",
        clip_controls=False,  # the exact case: no projection
        keep_trajectories=3,
        predict=True,
        predict_options={"samples": SAMPLES, "seed": 1},
    )
    return problem, plan, report


def _agrees(predicted: float, measured: float, runs: int, samples: int, z: float) -> bool:
    """``|p_hat - r| <= z sd`` with ``sd^2 = p (1 - p) (1/runs + 1/samples)``.

    Under an exact prediction, the measured rate ``r`` is binomial over ``runs`` and the predicted
    ``p_hat`` binomial over ``samples`` (model sampling), independent, around the same ``p``; the
    variance uses ``p_hat`` with a floor of one event in ``runs`` (a rate of 0 has a variance
    estimate of 0 but not a true variance of 0).
    """
    p = min(max(predicted, 1.0 / runs), 1.0 - 1.0 / runs)
    sd = math.sqrt(p * (1 - p) * (1.0 / runs + 1.0 / samples))
    return abs(predicted - measured) <= z * sd


def _rates(report, pred):
    """(name, predicted, measured) of every rate the comparison holds."""
    out = []
    for group, pred_rates in (
        (report.predicate_violations, pred.predicate_violation),
        (report.proposition_violations, pred.proposition_violation),
    ):
        for name, v in group.items():
            for r in ("belief", "state"):
                out.append((f"{name} ({r})", pred_rates[name][r], v[r]))
    for r in ("belief", "state"):
        out.append(
            (f"success ({r})", getattr(pred, f"{r}_success_estimate"), getattr(report, f"{r}_success_rate"))
        )
    return out


# --------------------------------------------------------------------------------------------
# Fields


def test_prediction_is_the_one_of_the_executed_loop(hold):
    problem, plan, report = hold
    pred = report.predicted
    assert isinstance(pred, ClosedLoopPrediction)
    assert pred.num_of_steps == report.num_of_steps == plan.num_of_steps and pred.samples == SAMPLES
    direct = predict_closed_loop(
        problem, plan, problem.switched_system, X0, control_domain=None, samples=SAMPLES, seed=1
    )
    np.testing.assert_array_equal(pred.augmented_cov, direct.augmented_cov)
    np.testing.assert_array_equal(pred.state_mean, direct.state_mean)
    assert pred.predicate_violation == direct.predicate_violation
    assert not pred.clip_probability.any()  # clip_controls=False: no projection predicted
    # Same seed without prediction: the same runs (the prediction draws from its own stream).
    plain = stl.validate(
        problem, plan, problem.switched_system, X0, runs=RUNS, seed=3, executor="serial", clip_controls=False
    )
    assert plain == report and plain.predicted is None
    assert plain.prediction_comparison() is None and "prediction" not in plain.as_dict()
    assert " pred " not in plain.summary()


def test_execution_options_reach_the_prediction(hold):
    """Steps, gains, clipping and process noise given to validate are the prediction's."""
    problem, plan, _ = hold
    gains = [[np.array([[0.3, 0.0], [0.0, 0.3]])] * 2]
    kw = {"num_of_steps": 8, "process_noise": "none", "lqr_gains": gains}
    report = stl.validate(
        problem, plan, problem.switched_system, X0, runs=2, seed=0, executor="serial",
        predict=True, predict_options={"samples": 0}, **kw,
    )  # fmt: skip
    direct = predict_closed_loop(problem, plan, problem.switched_system, X0, samples=0, **kw)
    assert report.predicted.num_of_steps == 8
    np.testing.assert_array_equal(report.predicted.tracking_gains, direct.tracking_gains)
    np.testing.assert_allclose(report.predicted.tracking_gains[0], gains[0][0])
    np.testing.assert_array_equal(report.predicted.augmented_cov, direct.augmented_cov)
    # without samples the rates are NaN: compared as None, never flagged
    cmp = report.prediction_comparison()
    entry = cmp["predicates"][next(iter(cmp["predicates"]))]["belief"]
    assert entry["predicted"] is None and entry["outside"] is None
    assert cmp["compared"] == 0 and cmp["outside"] == 0 and cmp["max_abs_diff"] is None
    with pytest.raises(InvalidArgumentError, match="predict_options"):
        stl.validate(problem, plan, problem.switched_system, X0, runs=1, executor="serial",
                     predict=True, predict_options={"process_noise": "none"})  # fmt: skip
    with pytest.raises(InvalidTypeError):
        stl.validate(problem, plan, problem.switched_system, X0, runs=1, executor="serial",
                     predict=True, predict_options=[("samples", 1)])  # fmt: skip


def test_comparison_summary_and_dict(hold):
    _, _, report = hold
    pred = report.predicted
    cmp = report.prediction_comparison()
    assert set(cmp["predicates"]) == set(report.predicate_violations)
    assert set(cmp["propositions"]) == set(report.proposition_violations)
    flagged = 0
    for name, v in cmp["predicates"].items():
        for r in ("belief", "state"):
            e = v[r]
            assert e["predicted"] == pred.predicate_violation[name][r]
            assert e["measured"] == report.predicate_violations[name][r]
            assert e["ci"] == report.predicate_violations[name][f"{r}_ci"]
            assert e["diff"] == pytest.approx(e["predicted"] - e["measured"])
            assert e["outside"] == (not e["ci"][0] <= e["predicted"] <= e["ci"][1])
            flagged += e["outside"]
    for r in ("belief", "state"):
        e = cmp["success"][r]
        assert e["predicted"] == getattr(pred, f"{r}_success_estimate")
        assert e["bound"] == getattr(pred, f"{r}_success_bound")
        assert e["bound_holds"] is (e["bound"] <= getattr(report, f"{r}_ci")[1])
    assert cmp["compared"] == 2 * (len(cmp["predicates"]) + len(cmp["propositions"]) + 1)
    assert cmp["max_abs_diff"] == max(abs(e["diff"]) for v in cmp["predicates"].values() for e in v.values())
    data = json.loads(json.dumps(report.as_dict()))
    assert data["prediction"]["outside"] == cmp["outside"] and data["prediction"]["samples"] == SAMPLES
    assert data["prediction"]["predicates"].keys() == cmp["predicates"].keys()
    text = report.summary()
    assert text.count(" pred ") == 2 + 2 * len(cmp["predicates"])
    assert f"{cmp['outside']} of {cmp['compared']} predicted rates outside" in text
    assert text.count(" !") == flagged + sum(bool(e["outside"]) for e in cmp["success"].values())


# --------------------------------------------------------------------------------------------
# Agreement where the prediction is exact


def test_exact_case_agrees_with_monte_carlo(hold):
    """Constant noise, no projection: every predicted rate within the sound tolerance.

    z = 3.9 is the two-sided normal quantile of 1e-4: with the rates of this problem (14), the
    chance that an exact prediction fails any of them is below 0.2% (Bonferroni) whatever the
    seeds. The rates are not trivial (the test below shows the check has power).
    """
    _, _, report = hold
    rates = _rates(report, report.predicted)
    assert max(m for name, _, m in rates if "success" not in name) >= 0.05  # something to compare
    bad = [(n, p, m) for n, p, m in rates if not _agrees(p, m, RUNS, SAMPLES, 3.9)]
    assert not bad
    assert report.predicted.state_success_bound <= report.state_ci[1]
    assert report.predicted.belief_success_bound <= report.belief_ci[1]


def test_a_wrong_prediction_is_caught(hold):
    """The same check rejects the prediction of another loop (no process noise): it has power."""
    problem, plan, report = hold
    wrong = predict_closed_loop(
        problem, plan, problem.switched_system, X0, control_domain=None, process_noise="none",
        samples=SAMPLES, seed=1,
    )  # fmt: skip
    assert any(not _agrees(p, m, RUNS, SAMPLES, 3.9) for _, p, m in _rates(report, wrong))


# --------------------------------------------------------------------------------------------
# Figure and command line


def test_execution_figure_draws_the_predicted_ellipses(hold):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    from idstlpy.plotting import plot_light_dark, plot_monte_carlo

    problem, plan, report = hold
    pred = report.predicted
    art = plot_monte_carlo(problem, plan, report.executions, report=report)  # taken from the report
    ws = art.workspace
    steps = pred.num_of_steps + 1
    assert len(ws.predicted_ellipses) == len(range(0, steps, max(1, steps // 25)))
    assert all(isinstance(e, Ellipse) and e in ws.ax.patches for e in ws.predicted_ellipses)
    np.testing.assert_allclose(ws.predicted_ellipses[3].center, pred.state_mean[3])
    np.testing.assert_allclose(ws.predicted.get_xdata(), pred.state_mean[:, 0])
    # the ellipse is the 95% region of the predicted true-state covariance
    sd = math.sqrt(pred.state_cov[5][0, 0])
    assert max(ws.predicted_ellipses[5].width, ws.predicted_ellipses[5].height) >= 2 * 2.4 * sd
    labels = [t.get_text() for t in art.legend.get_texts()]
    assert "predicted true state: 95% ellipses" in labels
    plt.close(art.figure)
    none = plot_monte_carlo(problem, plan, report.executions, report=report, predicted=False)
    assert not none.workspace.predicted_ellipses and none.workspace.predicted is None
    plt.close(none.figure)
    one = plot_light_dark(problem, plan, ax=None, predicted=pred, ellipse_every=5)
    assert len(one.predicted_ellipses) == len(range(0, steps, 5))
    plt.close(one.figure)
    with pytest.raises(InvalidTypeError, match="ClosedLoopPrediction"):
        plot_light_dark(problem, plan, predicted=report)


ONE_D = (
    'formula = "F[0,10] goal"\n[[modes]]\nA = [[1.0]]\nB = [[1.0]]\nW = [[0.05]]\nC = [[1.0]]\nV = [[0.1]]\n'
    "[control_domain]\nlow = [-1.0]\nhigh = [1.0]\n[initial_belief]\nmean = [0.0]\ncov = [0.01]\n"
    '[propositions.goal]\nconfidence = 0.9\nconstraints = ["2 <= x[0] <= 3"]\n[solver]\nrrt_timeout = 2\n'
    "seed = 0\n[validation]\nruns = 3\n"
)


def test_cli_validate_predict(tmp_path):
    path = tmp_path / "one.toml"
    path.write_text(ONE_D)
    out = tmp_path / "r"
    assert main(["validate", str(path), "--predict", "--out", str(out), "--quiet"]) == EXIT_OK
    (rec,) = out.glob("*.json")
    record = json.loads(rec.read_text())
    prediction = record["validation"]["prediction"]
    assert record["problem"]["overrides"] == {"validation.predict": True}
    assert set(prediction["predicates"]) == set(record["validation"]["predicate_violations"])
    assert {"belief", "state"} == set(prediction["success"])
    # the file's own switch, and its type check
    path.write_text(ONE_D + "predict = true\n")
    assert main(["validate", str(path), "--out", str(tmp_path / "s"), "--quiet"]) == EXIT_OK
    (rec,) = (tmp_path / "s").glob("*.json")
    assert "prediction" in json.loads(rec.read_text())["validation"]
    with pytest.raises(ProblemFileError, match="validation.predict: must be true or false"):
        stl.load_problem(ONE_D + 'predict = "yes"\n', name="bad.toml").build()
