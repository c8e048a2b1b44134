"""Plans as data: to_dict / from_dict through strict JSON, to_dataframe, len, np.asarray, pickle."""

from __future__ import annotations

import json
import pickle
import sys

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system
from idstlpy.trajectory import (
    BELIEF_TRAJECTORY_SCHEMA,
    REAL_TRAJECTORY_SCHEMA,
    ProbabilisticTSTrajectory,
    RealTrajectory,
)


@pytest.fixture(scope="module")
def case():
    problem = light_dark(deadline=30, hold=5)
    controls = np.vstack([np.tile([1.0, 0.0], (8, 1)), np.tile([-1.0, -1.0], (6, 1))])
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(len(controls), dtype=int), controls
    )
    xi_sim, xi_real = stl.simulate(
        problem.switched_system,
        plan,
        plan.num_of_steps,
        LIGHT_DARK_REAL_INITIAL_STATE,
        light_dark_real_system(),
        seed=0,
    )
    return problem, plan, xi_sim, xi_real


def _same_belief(a: ProbabilisticTSTrajectory, b: ProbabilisticTSTrajectory) -> None:
    np.testing.assert_array_equal(a.get_mean(), b.get_mean())
    np.testing.assert_array_equal(a.get_cov(), b.get_cov())
    np.testing.assert_array_equal(a.get_action(), b.get_action())
    np.testing.assert_array_equal(a.get_control(), b.get_control())


def test_belief_round_trip_through_strict_json_is_exact(case):
    problem, plan = case[0], case[1]
    data = plan.to_dict()
    assert data["schema"] == BELIEF_TRAJECTORY_SCHEMA
    assert data["num_of_steps"] == plan.num_of_steps and data["n"] == 2 and data["m"] == 2
    text = json.dumps(data, allow_nan=False)
    back = ProbabilisticTSTrajectory.from_dict(json.loads(text))
    _same_belief(plan, back)
    assert stl.satisfies(back, problem.stl_formula) == stl.satisfies(plan, problem.stl_formula)


def test_belief_from_dict_reads_the_legacy_result_plan(case):
    plan = case[1]
    legacy = {
        "mean": plan.get_mean().tolist(),
        "cov": plan.get_cov().tolist(),
        "action": plan.get_action().tolist(),
        "control": plan.get_control().tolist(),
    }
    _same_belief(plan, ProbabilisticTSTrajectory.from_dict(legacy))


def test_belief_of_no_step_keeps_its_input_dimension():
    traj = ProbabilisticTSTrajectory(np.zeros((1, 3)), np.zeros((1, 3, 3)), [], np.zeros((0, 2)))
    back = ProbabilisticTSTrajectory.from_dict(json.loads(json.dumps(traj.to_dict())))
    assert back.num_of_steps == 0 and back.n == 3 and back.m == 2 and len(back) == 1


def test_real_round_trip_writes_nan_as_null(case):
    xi_real = case[3]
    data = xi_real.to_dict()
    assert data["schema"] == REAL_TRAJECTORY_SCHEMA
    assert data["observation"][0] == [None, None]  # no observation at the start
    text = json.dumps(data, allow_nan=False)
    back = RealTrajectory.from_dict(json.loads(text))
    np.testing.assert_array_equal(back.get_state(), xi_real.get_state())
    np.testing.assert_array_equal(back.get_observation(), xi_real.get_observation())  # NaN == NaN here
    np.testing.assert_array_equal(back.get_action(), xi_real.get_action())
    np.testing.assert_array_equal(back.get_control(), xi_real.get_control())


def test_real_trajectory_without_sensor_round_trips():
    real = RealTrajectory(np.zeros((3, 2)), np.zeros((3, 0)), [0, 0], np.ones((2, 1)))
    back = RealTrajectory.from_dict(json.loads(json.dumps(real.to_dict())))
    assert back.get_observation().shape == (3, 0) and back.get_control().shape == (2, 1)


def test_from_dict_errors(case):
    plan, xi_real = case[1], case[3]
    with pytest.raises(InvalidArgumentError, match="expected schema 'idstlpy.belief_trajectory/1'"):
        ProbabilisticTSTrajectory.from_dict(xi_real.to_dict())
    with pytest.raises(InvalidArgumentError, match="expected schema 'idstlpy.real_trajectory/1'"):
        RealTrajectory.from_dict(plan.to_dict())
    with pytest.raises(InvalidArgumentError, match="expected schema"):
        RealTrajectory.from_dict({"state": []})  # no legacy form for real trajectories
    with pytest.raises(InvalidTypeError, match="must be a dict"):
        ProbabilisticTSTrajectory.from_dict([1, 2])
    data = plan.to_dict()
    del data["cov"]
    with pytest.raises(InvalidArgumentError, match="lacks the keys \\['cov'\\]"):
        ProbabilisticTSTrajectory.from_dict(data)
    data = plan.to_dict()
    data["action"] = [0.5] * plan.num_of_steps
    with pytest.raises(InvalidArgumentError, match="action must be integers"):
        ProbabilisticTSTrajectory.from_dict(data)
    data = plan.to_dict()
    data["mean"] = data["mean"][:-1]
    with pytest.raises(DimensionError, match="covs must have shape"):
        ProbabilisticTSTrajectory.from_dict(data)
    data = plan.to_dict()
    data["mean"][3][0] = None  # a NaN mean is not a plan
    with pytest.raises(InvalidArgumentError, match="finite"):
        ProbabilisticTSTrajectory.from_dict(data)
    with pytest.raises(DimensionError, match="mean must have 2 axes"):
        ProbabilisticTSTrajectory.from_dict({**plan.to_dict(), "mean": [1.0, 2.0]})


def test_len_counts_beliefs_and_num_of_steps_counts_transitions(case):
    plan, xi_sim, xi_real = case[1], case[2], case[3]
    for traj in (plan, xi_sim, xi_real):
        assert len(traj) == traj.num_of_steps + 1
    assert plan.num_of_beliefs == len(plan) == plan.get_mean().shape[0] == plan.get_action().shape[0] + 1


def test_asarray_is_the_means_not_an_object_scalar(case):
    plan, xi_real = case[1], case[3]
    arr = np.asarray(plan)
    assert arr.dtype == float and arr.shape == (len(plan), plan.n)
    np.testing.assert_array_equal(arr, plan.get_mean())
    assert np.asarray(plan, dtype=np.float32).dtype == np.float32
    copied = np.array(plan, copy=True)
    copied[0, 0] = 99.0
    assert plan.get_mean(0)[0] != 99.0
    np.testing.assert_array_equal(np.asarray(xi_real), xi_real.get_state())


def test_trajectories_pickle(case):
    plan, xi_real = case[1], case[3]
    back = pickle.loads(pickle.dumps(plan))
    _same_belief(plan, back)
    real = pickle.loads(pickle.dumps(xi_real))
    np.testing.assert_array_equal(real.get_state(), xi_real.get_state())


def test_to_dataframe_columns_and_values(case):
    pd = pytest.importorskip("pandas")
    plan = case[1]
    df = plan.to_dataframe()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == [
        "step",
        "mode",
        "control_0",
        "control_1",
        "mean_0",
        "mean_1",
        "std_0",
        "std_1",
    ]
    assert len(df) == len(plan)
    np.testing.assert_array_equal(df["step"], np.arange(len(plan)))
    np.testing.assert_array_equal(df["mode"].iloc[:-1].to_numpy(dtype=int), plan.get_action())
    assert df["mode"].isna().iloc[-1] and df["control_0"].isna().iloc[-1]
    np.testing.assert_array_equal(df[["control_0", "control_1"]].to_numpy()[:-1], plan.get_control())
    np.testing.assert_array_equal(df[["mean_0", "mean_1"]].to_numpy(), plan.get_mean())
    np.testing.assert_allclose(df["std_1"].to_numpy(), np.sqrt(plan.get_cov()[:, 1, 1]), rtol=0, atol=0)


def test_to_dataframe_without_pandas_says_so(case, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas -> ImportError
    with pytest.raises(InvalidArgumentError, match="pip install pandas"):
        case[1].to_dataframe()


def test_real_trajectory_rejects_observations_of_the_wrong_length():
    with pytest.raises(DimensionError, match="observations"):
        RealTrajectory(np.zeros((3, 2)), np.zeros((2, 1)), [0, 0], np.zeros((2, 1)))
