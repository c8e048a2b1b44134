"""Batch runs: jobs as plain data, seeds, resumable result files, and identical records on every
backend (in-process, process pool, Dask LocalCluster)."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.batch import (
    DEFAULT_SEED,
    DaskExecutor,
    InProcessExecutor,
    Job,
    comparable,
    load_sweep,
    make_executor,
    result_path,
    run_job,
    run_jobs,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
LIGHT_DARK = EXAMPLES / "light_dark.toml"
UNSAT = EXAMPLES / "unsatisfiable.toml"
FAST = {"solver.rrt_timeout": 5, "solver.time_limit": 60}


def _jobs() -> list[Job]:
    """Small jobs: two seeds of the light-dark example, a proof of infeasibility, a validation."""
    return [
        Job.from_file(LIGHT_DARK, "solve", FAST, seed=1),
        Job.from_file(LIGHT_DARK, "solve", FAST, seed=2),
        Job.from_file(UNSAT, "solve", {}, seed=3),
        Job.from_file(LIGHT_DARK, "validate", {**FAST, "validation.runs": 3}, seed=4),
    ]


def test_job_is_plain_data_with_a_stable_key():
    job = Job.from_file(LIGHT_DARK, "solve", FAST, seed=1)
    assert Job.from_dict(job.as_dict()) == job
    assert pickle.loads(pickle.dumps(job.as_dict())) == job.as_dict()
    same = Job(job.kind, job.problem_text, "elsewhere.toml", dict(FAST), 1)
    assert same.key == job.key and len(job.key) == 16
    assert Job.from_file(LIGHT_DARK, "solve", FAST, seed=2).key != job.key
    assert Job.from_file(LIGHT_DARK, "validate", FAST, seed=1).key != job.key
    assert Job.from_file(LIGHT_DARK, "solve", {**FAST, "solver.goal_bias": 0.5}, seed=1).key != job.key
    with pytest.raises(stl.InvalidArgumentError):
        Job("optimize", job.problem_text)
    with pytest.raises(stl.InvalidArgumentError):
        Job("solve", job.problem_text, seed=-1)


def test_run_job_record():
    record = run_job(Job.from_file(LIGHT_DARK, "solve", FAST, seed=1).as_dict())
    json.dumps(record, allow_nan=False)
    assert record["schema"] == "idstlpy.result/1" and record["kind"] == "solve"
    assert record["status"] == "found" and record["error"] is None
    assert record["seed"] == 1 and record["seed_source"] == "job"
    assert record["problem"]["overrides"] == FAST
    assert record["problem"]["text"] == LIGHT_DARK.read_text()
    assert record["problem"]["sha256"] == hashlib.sha256(LIGHT_DARK.read_bytes()).hexdigest()
    assert record["formula"] == "(free_space U[0,240] G[0,40] target)"
    assert record["solver_options"]["seed"] == 1 and record["solver_options"]["rrt_timeout"] == 5
    plan = record["plan"]
    assert len(plan["action"]) == len(plan["control"]) == len(plan["mean"]) - 1
    assert "time_total" in record["timing"]["solver"] and record["timing"]["wall_time"] > 0
    # the plan is the one the Python API finds with the same seed, and reads back as a result
    problem = stl.problem_file.load_problem(LIGHT_DARK).build().problem
    for mode in problem.switched_system.system_modes:  # the file's [execution.lqr], as the job sets
        mode.compute_finite_horizon_lqr(5, np.eye(2), np.eye(2), 0.05 * np.eye(2))
    direct = problem.solve_result(rrt_timeout=5, time_limit=60, seed=1)
    np.testing.assert_array_equal(direct.trajectory.get_control(), np.array(plan["control"]))
    again = stl.SolveResult.from_dict(record)
    assert again.status == "found" and stl.satisfies(again.trajectory, problem.stl_formula)


def test_a_file_without_seed_uses_the_default_seed():
    text = LIGHT_DARK.read_text()
    assert "seed" not in text.split("[solver]")[1].split("[execution]")[0]
    a = run_job(Job("solve", text, "ld.toml", FAST))
    b = run_job(Job("solve", text, "ld.toml", FAST))
    assert a["seed"] == DEFAULT_SEED and a["seed_source"] == "default"
    assert comparable(a) == comparable(b)  # the same plan on every run
    seeded = run_job(Job("solve", text, "ld.toml", {**FAST, "solver.seed": 5}))
    assert seeded["seed"] == 5 and seeded["seed_source"] == "file"


def test_failing_job_is_a_record_not_an_exception():
    record = run_job(Job.from_file(LIGHT_DARK, "solve", {"solver.budget": 1}, seed=0))
    assert record["status"] == "error" and record["plan"] is None
    assert record["error"]["type"] == "ProblemFileError"
    assert "solver.budget (override)" in record["error"]["message"]
    json.dumps(record, allow_nan=False)


def test_validate_a_saved_plan_without_solving(tmp_path):
    solved = run_job(Job.from_file(LIGHT_DARK, "solve", FAST, seed=1))
    job = Job.from_file(LIGHT_DARK, "validate", {**FAST, "validation.runs": 3}, seed=1, plan=solved)
    record = run_job(job)
    assert record["status"] == "found" and record["plan_source"] == "saved"
    assert record["check"]["satisfies"] and record["check"]["same_problem"]
    assert record["check"]["max_deviation"] < 1e-9
    assert record["plan"] == solved["plan"] and record["validation"]["runs"] == 3
    assert "solver" not in record["timing"]  # nothing was solved
    # the same plan under a stricter problem is rejected, with a reason
    # (a hold of 400 steps: no plan of the original problem is that long, whatever the sampler drew)
    strict = Job.from_file(
        LIGHT_DARK, "validate", {"formula": "(free_space U[0,240] G[0,400] target)"}, plan=solved
    )
    rejected = run_job(strict)
    assert rejected["status"] == "rejected" and not rejected["check"]["satisfies"]
    assert "does not satisfy" in rejected["reason"] and rejected["validation"] is None
    # a tampered plan does not re-roll to its own beliefs
    tampered = json.loads(json.dumps(solved))
    tampered["plan"]["mean"][3][0] += 0.5
    bad = run_job(Job.from_file(LIGHT_DARK, "validate", FAST, plan=tampered))
    assert bad["status"] == "rejected" and "differ" in bad["reason"]
    with pytest.raises(stl.InvalidArgumentError):
        Job.from_file(LIGHT_DARK, "solve", plan=solved)


def test_sweep_file(tmp_path):
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text(
        f'problem = "{LIGHT_DARK}"\nseed = 7\nrepeats = 2\n\n'
        '[grid]\n"solver.goal_bias" = [0.1, 0.25]\nsolver.rrt_timeout = [1, 2, 3]\n\n'
        '[[cases]]\n"initial_belief.mean" = [0.0, 2.5]\n\n[[cases]]\n"initial_belief.mean" = [0.5, 2.0]\n'
    )
    sweep = load_sweep(sweep_file)
    jobs = sweep.jobs()
    assert len(jobs) == 2 * 2 * 3 * 2 and sweep.kind == "solve"
    assert jobs[0].overrides == {
        "initial_belief.mean": [0.0, 2.5],
        "solver.goal_bias": 0.1,
        "solver.rrt_timeout": 1,
    }
    seeds = [j.seed for j in jobs]
    assert len(set(seeds)) == len(seeds)
    assert [j.seed for j in load_sweep(sweep_file).jobs()] == seeds  # reproducible
    assert [j.seed for j in sweep.jobs(seed=8)] != seeds
    # appending repeats keeps the seeds (and result files) of the existing jobs
    sweep_file.write_text(sweep_file.read_text().replace("repeats = 2", "repeats = 3"))
    more = load_sweep(sweep_file).jobs()
    assert {j.key for j in jobs} <= {j.key for j in more}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('problem = "{p}"\nkind = "optimize"\n', "sweep.toml:2: kind: must be one of"),
        ('problem = "{p}"\nseeds = 1\n', "sweep.toml:2: seeds: unknown key"),
        ('problem = "absent.toml"\n', "sweep.toml:1: problem: problem file"),
        ("seed = 1\n", "missing required key 'problem'"),
        ('problem = "{p}"\n[grid]\n"solver.goal_bias" = 0.5\n', "sweep.toml:3: grid.solver.goal_bias"),
        ('problem = "{p}"\n[grid]\n"solver.budget" = [1]\n', "solver.budget (override): unknown key"),
        ('problem = "{p}"\n[[cases]]\n"modes[0].V.scale" = "open(1)"\n', "calling 'open'"),
    ],
)
def test_bad_sweep_files(tmp_path, text, message):
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text(text.replace("{p}", str(LIGHT_DARK)))
    with pytest.raises(stl.ProblemFileError) as info:
        load_sweep(sweep_file)
    assert message in str(info.value)


def test_results_are_written_and_resumed(tmp_path):
    jobs = [Job.from_file(UNSAT, "solve", {}, seed=s) for s in (1, 2)]
    bad = Job.from_file(UNSAT, "solve", {"solver.budget": 1}, seed=1)
    seen = []
    records = run_jobs(
        jobs + [bad, jobs[0]], tmp_path, "inprocess", progress=lambda d, t, r: seen.append((d, t))
    )
    assert seen == [(1, 3), (2, 3), (3, 3)]  # the duplicate job runs once
    assert [r["status"] for r in records] == ["infeasible", "infeasible", "error", "infeasible"]
    for job in jobs + [bad]:
        assert json.loads(result_path(tmp_path, job).read_text())["id"] == job.key
    stamp = result_path(tmp_path, jobs[0]).stat().st_mtime_ns
    again = run_jobs(jobs + [bad], tmp_path, "inprocess")
    assert [r["timing"]["cached"] for r in again] == [True, True, False]  # failed jobs rerun
    assert result_path(tmp_path, jobs[0]).stat().st_mtime_ns == stamp
    assert [comparable(r) for r in again[:2]] == [comparable(r) for r in records[:2]]
    fresh = run_jobs(jobs[:1], tmp_path, "inprocess", resume=False)
    assert fresh[0]["timing"]["cached"] is False


def test_resume_checks_the_id_and_the_problem_of_each_record(tmp_path):
    jobs = [Job.from_file(UNSAT, "solve", {}, seed=s) for s in (1, 2, 3, 4)]
    first = run_jobs(jobs, tmp_path, "inprocess")
    paths = [result_path(tmp_path, j) for j in jobs]
    # a stub, another job's record, a record of another problem text, a record of an old schema
    paths[0].write_text(json.dumps({"schema": "idstlpy.result/1", "id": jobs[0].key, "status": "infeasible"}))
    paths[1].write_text(paths[2].read_text())
    other = json.loads(paths[2].read_text())
    other["problem"]["sha256"] = "0" * 64
    paths[2].write_text(json.dumps(other))
    old = json.loads(paths[3].read_text())
    old["schema"] = "idstlpy.result/0"
    paths[3].write_text(json.dumps(old))
    again = run_jobs(jobs, tmp_path, "inprocess")
    assert [r["timing"]["cached"] for r in again] == [False, False, False, False]
    assert [comparable(r) for r in again] == [comparable(r) for r in first]
    assert all(json.loads(p.read_text())["id"] == j.key for p, j in zip(paths, jobs, strict=True))
    assert [r["timing"]["cached"] for r in run_jobs(jobs, tmp_path, "inprocess")] == [True] * 4


def test_executors_by_name():
    assert isinstance(make_executor("inprocess"), InProcessExecutor)
    with pytest.raises(stl.InvalidArgumentError):
        make_executor("cluster")
    with pytest.raises(stl.InvalidArgumentError):
        make_executor("processes", workers=0)
    with pytest.raises(stl.InvalidArgumentError, match="dask"):
        make_executor("processes", scheduler="tcp://localhost:8786")
    future = InProcessExecutor().submit(divmod, 7, 2)
    assert future.result() == (3, 1)
    assert isinstance(InProcessExecutor().submit(divmod, 1, 0).exception(), ZeroDivisionError)


@pytest.fixture(scope="module")
def reference_records():
    return [comparable(r) for r in run_jobs(_jobs(), None, "inprocess")]


def test_reference_statuses(reference_records):
    assert [r["status"] for r in reference_records] == ["found", "found", "infeasible", "found"]
    assert [r["validation"] is None for r in reference_records] == [True, True, True, False]
    report = reference_records[3]["validation"]
    assert report["runs"] == 3 and 0.0 <= report["state_success_rate"] <= 1.0


def test_process_pool_gives_identical_records(tmp_path, reference_records):
    records = run_jobs(_jobs(), tmp_path, "processes", workers=2)
    assert [r["timing"]["backend"] for r in records] == ["processes"] * 4
    assert [comparable(r) for r in records] == reference_records
    on_disk = [json.loads(result_path(tmp_path, j).read_text()) for j in _jobs()]
    assert [comparable(r) for r in on_disk] == reference_records


def test_dask_local_cluster_gives_identical_records(reference_records):
    import distributed  # noqa: F401  (the dask extra is part of the test extras)

    executor = DaskExecutor(workers=2, processes=False)
    try:
        records = run_jobs(_jobs(), None, executor)
    finally:
        executor.shutdown()
    assert [comparable(r) for r in records] == reference_records


def test_sweep_seeds_give_identical_records_across_backends(tmp_path):
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text(
        f'problem = "{LIGHT_DARK}"\nseed = 11\n[grid]\n"solver.rrt_timeout" = [5]\n'
        '"solver.goal_bias" = [0.25, 0.5]\n'
    )
    jobs = load_sweep(sweep_file).jobs()
    a = run_jobs(jobs, tmp_path / "a", "inprocess")
    b = run_jobs(load_sweep(sweep_file).jobs(), tmp_path / "b", "processes", workers=2)
    assert [comparable(r) for r in a] == [comparable(r) for r in b]
    assert sorted(p.name for p in (tmp_path / "a").glob("*.json")) == sorted(
        p.name for p in (tmp_path / "b").glob("*.json")
    )


# ------------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------------


def _cli(argv: list[str]) -> int:
    from idstlpy.cli import main

    return main(argv)


def test_cli_solve(tmp_path, capsys):
    code = _cli(["solve", str(UNSAT), "--out", str(tmp_path), "--seed", "3", "--set", "solver.rrt_timeout=2"])
    out, err = capsys.readouterr()
    assert code == 1  # ran, no plan
    assert "infeasible" in out and "total: 1 infeasible" in out
    assert "solving" in err and "(seed 3)" in err  # the progress line of a single solve
    (path,) = tmp_path.glob("*.json")
    record = json.loads(path.read_text())
    assert record["seed"] == 3 and record["problem"]["overrides"] == {"solver.rrt_timeout": 2}
    assert f"result: {path}" in out
    args = ["solve", str(UNSAT), "--out", str(tmp_path), "--seed", "3", "--quiet"]
    args += ["--set", "solver.rrt_timeout=2"]
    assert _cli(args) == 1
    out, err = capsys.readouterr()
    assert "reused" in err and "infeasible" in out
    assert _cli([*args, "--no-resume"]) == 1
    assert capsys.readouterr().err == ""


def test_cli_bad_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(UNSAT.read_text().replace("rrt_timeout = 5", "rrt_timeout = 5\nbudget = 3"))
    assert _cli(["solve", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:" in err and "solver.budget" in err and err.count("\n") == 1
    assert _cli(["solve", str(UNSAT), "--set", "solver.nope=1", "--out", str(tmp_path)]) == 2
    assert not list(tmp_path.glob("*.json"))


def test_cli_sweep(tmp_path, capsys):
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text(f'problem = "{UNSAT}"\nrepeats = 2\n[grid]\n"solver.rrt_timeout" = [1, 2]\n')
    out_dir = tmp_path / "out"
    assert _cli(["sweep", str(sweep_file), "--out", str(out_dir), "--executor", "inprocess"]) == 1
    out, err = capsys.readouterr()
    assert "total: 4 infeasible" in out and "4/4 jobs" in err
    assert len(list(out_dir.glob("*.json"))) == 4
    assert _cli(["sweep", str(sweep_file), "--out", str(out_dir), "--executor", "inprocess"]) == 1
    assert "4 cached" in capsys.readouterr().err
    found = tmp_path / "found.toml"
    found.write_text(f'problem = "{LIGHT_DARK}"\n[grid]\n"solver.rrt_timeout" = [5]\n')
    assert _cli(["sweep", str(found), "--out", str(out_dir), "--executor", "inprocess", "--quiet"]) == 0


def test_dask_by_name_with_worker_processes(tmp_path, reference_records):
    import distributed  # noqa: F401  (the dask extra is part of the test extras)

    records = run_jobs(_jobs()[2:3], tmp_path, "dask", workers=1)
    assert records[0]["timing"]["backend"] == "dask"
    assert [comparable(r) for r in records] == reference_records[2:3]


def test_main_entry_point(tmp_path, capsys):
    from idstlpy import cli

    assert cli.main(["solve", str(UNSAT), "--out", str(tmp_path), "--quiet"]) == 1
    assert "infeasible" in capsys.readouterr().out


_ORPHAN_SCRIPT = """
import os, sys, time
from idstlpy.batch.executors import make_executor

if __name__ == "__main__":
    ex = make_executor("processes", workers=1)
    print(ex.submit(os.getpid).result(), flush=True)
    ex.submit(time.sleep, 120)
    time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    if stat.exists():
        try:
            return stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"  # a zombie is dead
        except (OSError, IndexError):
            return False
    return True


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_pool_workers_stop_when_their_parent_dies(tmp_path):
    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN_SCRIPT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        assert _alive(worker)
        parent.send_signal(signal.SIGKILL)  # no clean-up of any kind runs in the parent
        parent.wait(timeout=10)
        deadline = time.monotonic() + 15
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker), "the pool worker outlived its parent"
    finally:
        parent.kill()
        parent.stdout.close()


def test_batch_is_a_package_without_cycles():
    import ast

    import idstlpy.batch as batch

    package_dir = Path(batch.__file__).parent
    graph: dict[str, set[str]] = {}
    for path in package_dir.glob("*.py"):
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                deps |= {node.module.split(".")[0]} if node.module else {a.name for a in node.names}
        graph[path.stem] = deps - {path.stem, "__init__"}
    assert {"jobs", "executors", "runner", "sweeps"} <= set(graph)
    assert graph["executors"] == set() and "runner" not in graph["jobs"] | graph["sweeps"]

    def visit(node: str, stack: tuple[str, ...]) -> None:
        assert node not in stack, f"import cycle: {' -> '.join(stack + (node,))}"
        for dep in graph.get(node, ()):
            visit(dep, stack + (node,))

    for node in graph:
        visit(node, ())
