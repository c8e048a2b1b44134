"""Re-planning and the start check from problem files, batch jobs and the command line.

``[validation] replan``, ``[validation.replan_options]`` and ``[validation.start_check]`` are
the keywords of ``stl.validate(replan=..., replan_options=...)`` and ``stl.start_check``: a job
must give exactly what the Python recipe gives with the same seeds, and every bad value is a
``ProblemFileError`` naming the file, line and field.
"""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.batch import Job, comparable, run_job
from idstlpy.batch.jobs import derived_seed, replan_summary
from idstlpy.batch.records import plan_from_record
from idstlpy.cli import EXIT_OK, EXIT_USAGE, main
from idstlpy.execution.precheck import START_CHECK_KEYWORDS
from idstlpy.execution.replanner import EXECUTOR_KEYWORDS
from idstlpy.execution.validation import REPLAN_OPTION_KEYS
from idstlpy.problem_file import apply_overrides, load_problem, schema

# test_replanning.py's noisy integrator as a file: LP-exact, solves in milliseconds.
TINY = """\
name = "tiny"
formula = "F[0,12] G[0,4] target"

[[modes]]
A = [[1.0, 0.0], [0.0, 1.0]]
B = [[0.5, 0.0], [0.0, 0.5]]
W = [[0.08, 0.0], [0.0, 0.08]]
C = [[1.0, 0.0], [0.0, 1.0]]
V = [[0.1, 0.0], [0.0, 0.1]]

[control_domain]
low = [-1.0, -1.0]
high = [1.0, 1.0]

[initial_belief]
mean = [0.0, 0.0]
cov = [0.05, 0.05]

[propositions.target]
confidence = 0.9
constraints = ["1.4 <= x[0] <= 2.6", "-0.6 <= x[1] <= 0.6"]

[solver]
rrt_timeout = 2
seed = 0

[execution]
real_initial_state = [0.2, -0.1]

[[execution.real_system]]
A = [[1.0, 0.0], [0.0, 1.0]]
B = [[0.25, 0.0], [0.0, 0.25]]

[validation]
runs = 5
seed = 3
replan = "on_risk"

[validation.replan_options]
risk = 1.0
check_every = "none"
drift = 0.95
max_replans = 1

[validation.start_check]
risk = 1.0
resolves = 1
adopt = "always"
"""
# line numbers of TINY, for the error messages
RISK_LINE = TINY.splitlines().index("risk = 1.0") + 1
START_LINE = TINY.splitlines().index("[validation.start_check]") + 1
REPLAN_LINE = TINY.splitlines().index('replan = "on_risk"') + 1


def _tiny(tmp_path: Path, text: str = TINY) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------------
# the tables
# ------------------------------------------------------------------------------------------------


def test_tables_are_validate_and_start_check_keywords():
    execution = load_problem(TINY).build().execution
    assert execution.replan == "on_risk"
    assert execution.replan_options == {"risk": 1.0, "check_every": None, "drift": 0.95, "max_replans": 1}
    assert execution.start_check == {"risk": 1.0, "resolves": 1, "adopt": "always"}
    # "none" is Python's None (TOML has no null); without the tables nothing re-plans
    spec = apply_overrides(
        load_problem(TINY),
        {
            "validation.replan": "none",
            "validation.replan_options.drift": "none",
            "validation.replan_options.solver_options": {"guarantee": "closed_loop", "rrt_timeout": 1},
        },
    )
    execution = spec.build().execution
    assert execution.replan is None and execution.replan_options["drift"] is None
    assert execution.replan_options["solver_options"] == {"guarantee": "closed_loop", "rrt_timeout": 1.0}
    bare = load_problem(TINY.split("[validation]")[0]).build().execution
    assert bare.replan is None and bare.replan_options == {} and bare.start_check is None


def test_the_keys_are_the_keywords_of_execute_and_start_check():
    # execute's `options` and start_check's are the file's [solver] table: not keys of their own
    assert set(schema.REPLAN_OPTION_KEYS) == set(REPLAN_OPTION_KEYS) - {"options"}
    executor = {"options", "clip_controls", "process_noise", "lqr_gains", "default_lqr", "policy"}
    params = inspect.signature(stl.start_check).parameters
    keywords = {k for k, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    keywords |= START_CHECK_KEYWORDS | EXECUTOR_KEYWORDS  # start_check's **options
    assert set(schema.START_CHECK_KEYS) == keywords - executor - {"plant"}


BAD = [
    # (override key, value, field, message)
    ("validation.replan", "sometimes", "validation.replan", "must be one of 'none', 'on_risk', 'every'"),
    ("validation.replan", True, "validation.replan", "got a boolean"),
    ("validation.replan_options.risk", 1.5, "validation.replan_options.risk", "[0.0, 1.0]"),
    ("validation.replan_options.every", 0, "validation.replan_options.every", ">= 1"),
    ("validation.replan_options.check_every", "never", "validation.replan_options.check_every",
     "an integer or 'none', got 'never'"),
    ("validation.replan_options.check_every", 2.5, "validation.replan_options.check_every", "integer"),
    ("validation.replan_options.drift", 1.0, "validation.replan_options.drift", "(0, 1)"),
    ("validation.replan_options.drift", "wide", "validation.replan_options.drift", "or 'none'"),
    ("validation.replan_options.risk_measure", "median", "validation.replan_options.risk_measure",
     "'bound', 'estimate'"),
    ("validation.replan_options.risk_on", "plan", "validation.replan_options.risk_on", "'belief'"),
    ("validation.replan_options.risk_samples", 0, "validation.replan_options.risk_samples", ">= 1"),
    ("validation.replan_options.max_replans", -1, "validation.replan_options.max_replans", ">= 0"),
    ("validation.replan_options.adopt", "never", "validation.replan_options.adopt", "'better', 'always'"),
    ("validation.replan_options.replan_time_limit", 0, "validation.replan_options.replan_time_limit",
     "> 0"),
    ("validation.replan_options.options", {}, "validation.replan_options.options", "unknown key"),
    ("validation.replan_options.solver_options.rrt_timeout", "x",
     "validation.replan_options.solver_options.rrt_timeout", "must be a number"),
    ("validation.replan_options.solver_options.budget", 1,
     "validation.replan_options.solver_options.budget", "unknown key 'budget'"),
    # checked together with [solver]: 20 steps at least, but [solver] keeps at most 15
    ("validation.start_check.solver_options.min_num_of_steps", 20,
     "validation.start_check.solver_options.min_num_of_steps", "max_num_of_steps"),
    ("validation.start_check.resolves", -1, "validation.start_check.resolves", ">= 0"),
    ("validation.start_check.seed", -2, "validation.start_check.seed", ">= 0"),
    ("validation.start_check.every", 3, "validation.start_check.every", "unknown key 'every'"),
    ("validation.start_check", 0.99, "validation.start_check", "must be a table"),
]  # fmt: skip


@pytest.mark.parametrize(("key", "value", "field", "message"), BAD)
def test_bad_values_name_the_field(key, value, field, message):
    with pytest.raises(stl.ProblemFileError) as info:
        apply_overrides(load_problem(TINY), {key: value})
    assert str(info.value).startswith(f"<string>: {field} (override): "), str(info.value)
    assert message in str(info.value) and info.value.field == field


# the values of BAD that execute / start_check themselves take (the file's own words aside)
_TABLES = {"replan_options": schema.REPLAN_OPTION_KEYS, "start_check": schema.START_CHECK_KEYS}
PYTHON_BAD = [
    (table, name, value)
    for key, value, _, _ in BAD
    if key.count(".") == 2
    and (table := key.split(".")[1]) in _TABLES
    and (name := key.split(".")[2]) in _TABLES[table]
    and name != "seed"  # start_check(seed=-2) is a SeedSequence's error, not one naming the seed
]


@pytest.fixture(scope="module")
def tiny_case():
    problem, solver_kwargs, execution = load_problem(TINY).build()
    plan = problem.solve(**solver_kwargs)
    assert plan is not None, problem.last_result
    return problem, plan, execution


@pytest.mark.parametrize(("table", "key", "value"), PYTHON_BAD)
def test_the_file_rejects_what_python_rejects(tiny_case, table, key, value):
    """The file's checks are execute's and start_check's: a value rejected here is rejected there."""
    problem, plan, execution = tiny_case
    with pytest.raises(stl.IdstlpyError, match=key):
        if table == "start_check":
            stl.start_check(problem, plan, **{key: value})
        else:
            stl.execute(
                problem, plan, execution.real_system, execution.real_initial_state, seed=0, replan="on_risk",
                **{key: value},
            )  # fmt: skip


def test_bad_values_in_the_file_name_the_line(tmp_path):
    path = _tiny(tmp_path, TINY.replace("risk = 1.0", "risk = 2.0", 1))
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    assert str(info.value).startswith(f"{path}:{RISK_LINE}: validation.replan_options.risk: ")
    path = _tiny(tmp_path, TINY.replace("resolves = 1", "resolves = 1\nwhen = 0"))
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    assert str(info.value).startswith(f"{path}:{START_LINE + 3}: validation.start_check.when: unknown key")
    path = _tiny(tmp_path, TINY.replace('replan = "on_risk"', 'replan = "always"'))
    with pytest.raises(stl.ProblemFileError, match=f"{path}:{REPLAN_LINE}: validation.replan: "):
        load_problem(path)


# ------------------------------------------------------------------------------------------------
# jobs: what the Python recipe gives with the same seeds
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_record():
    return run_job(Job("validate", TINY, "tiny.toml"))


def test_a_validate_job_is_the_python_recipe(tiny_record):
    record = tiny_record
    assert record["status"] == "found", record["error"]
    spec = load_problem(TINY)
    problem, solver_kwargs, execution = spec.build()
    options = stl.SolverOptions.make(**{**solver_kwargs, "seed": record["seed"]})
    plan = plan_from_record(record)
    # the start check, made once: the file's seed rule gives a child of the solver's seed
    section = record["start_check"]
    assert section["seed"] == derived_seed(record["seed"], 2)
    checked = stl.start_check(problem, plan, seed=section["seed"], options=options, risk=1.0, resolves=1,
                              adopt="always")  # fmt: skip
    assert checked.replaced and section["replaced"] is True
    assert section["initial_predicted"] == checked.initial_predicted
    assert section["predicted"] == checked.predicted
    (resolve,) = section["resolves"]
    (replan,) = checked.replans
    assert resolve["status"] == replan.status == "found" and resolve["seed"] == replan.seed
    assert resolve["reason"] == "start" and "solve_time" not in resolve
    saved = section["plan"]
    assert np.array_equal(np.array(saved["mean"]), checked.plan.get_mean())
    assert np.array_equal(np.array(saved["action"]), checked.plan.get_action())
    assert section["margin"] == pytest.approx(stl.robustness(checked.plan, problem.stl_formula))
    # the runs: validate(replan=...) on the checked plan, [validation] seed, the file's [solver]
    replan_options = {"risk": 1.0, "check_every": None, "drift": 0.95, "max_replans": 1, "options": options}
    report = stl.validate(
        problem, checked.plan, execution.real_system, execution.real_initial_state, runs=5, seed=3,
        executor="serial", replan="on_risk", replan_options=replan_options,
    )  # fmt: skip
    validation = record["validation"]
    assert validation["seed"] == 3 and validation["plan_margin"] == pytest.approx(section["margin"])
    assert validation["replans"] == list(report.replans)
    assert validation["state_success_rate"] == report.state_success_rate
    assert validation["belief_success_rate"] == report.belief_success_rate
    assert validation["replan_summary"] == replan_summary("on_risk", report.replans)
    assert validation["replan_summary"]["runs_replanned"] >= 1  # the slow real system drifts
    assert record["timing"]["start_check"] >= 0.0


def test_jobs_with_replanning_are_reproducible_and_the_job_seed_decides(tiny_record):
    again = run_job(Job("validate", TINY, "tiny.toml"))
    assert comparable(again) == comparable(tiny_record)
    seeded = run_job(Job("validate", TINY, "tiny.toml", {"validation.start_check.seed": 5}, seed=7))
    assert seeded["start_check"]["seed"] == derived_seed(7, 2)  # a job's seed overrides the file's
    own = run_job(Job("validate", TINY, "tiny.toml", {"validation.start_check.seed": 5}))
    assert own["start_check"]["seed"] == 5


def test_summary_of_replans():
    assert replan_summary("every", [0, 2, 1, 0]) == {
        "policy": "every", "runs_replanned": 2, "total": 3, "mean": 0.75, "max": 2,
    }  # fmt: skip


# ------------------------------------------------------------------------------------------------
# the command line
# ------------------------------------------------------------------------------------------------


def test_cli_replan_flag_and_overrides(tmp_path, capsys):
    path = _tiny(tmp_path, TINY.split("[validation.replan_options]")[0].replace('replan = "on_risk"\n', ""))
    out = tmp_path / "every"
    # (--target 0,0: this test is about the flags; the tiny plan's rates do not matter)
    args = ["validate", str(path), "--quiet", "--out", str(out), "--replan", "every", "--target", "0,0"]
    sets = ["--set", "validation.replan_options.every=3", "--set", "validation.runs=2"]
    assert main([*args, *sets]) == EXIT_OK
    (record,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert record["problem"]["overrides"]["validation.replan"] == "every"
    assert record["validation"]["replan_summary"]["policy"] == "every"
    assert len(record["validation"]["replans"]) == 2 and min(record["validation"]["replans"]) >= 1
    assert record["start_check"] is None
    # --replan none: a fixed plan, no replan fields (the record of a plain validation)
    out = tmp_path / "none"
    none = ["validate", str(path), "--quiet", "--out", str(out), "--replan", "none", "--target", "0,0"]
    assert main(none) == EXIT_OK
    (record,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert "replans" not in record["validation"] and "replan_summary" not in record["validation"]
    # a bad value is an input error naming the field, before anything runs
    bad = ["--set", 'validation.replan_options.check_every="never"']
    assert main(["validate", str(path), "--out", str(tmp_path / "bad"), *bad]) == EXIT_USAGE
    assert "validation.replan_options.check_every (override)" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_sweep_over_the_replan_policy(tmp_path):
    from idstlpy.batch import load_sweep

    _tiny(tmp_path)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(
        'problem = "tiny.toml"\nkind = "validate"\n[grid]\n"validation.replan" = ["none", "every"]\n'
    )
    jobs = load_sweep(sweep).jobs()
    assert [j.overrides for j in jobs] == [{"validation.replan": "none"}, {"validation.replan": "every"}]
    sweep.write_text('problem = "tiny.toml"\n[grid]\n"validation.replan_options.drift" = [0.9, 1.5]\n')
    with pytest.raises(stl.ProblemFileError, match="validation.replan_options.drift"):
        load_sweep(sweep)
