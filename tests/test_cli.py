"""The ``idstlpy`` command: help everywhere, one-line errors, and the light-dark demo end to end."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import idstlpy
import idstlpy as stl
from idstlpy.cli import _COMMAND_MODULES, EXIT_FAILED, EXIT_NO_PLAN, EXIT_OK, EXIT_USAGE, build_parser, main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PACKAGE_EXAMPLES = Path(idstlpy.__file__).parent / "examples"
UNSAT = EXAMPLES / "unsatisfiable.toml"
LIGHT_DARK = EXAMPLES / "light_dark.toml"
FAST = ["--set", "solver.rrt_timeout=5", "--set", "solver.time_limit=60"]


def test_command_modules_tuple():
    assert _COMMAND_MODULES == ("demo", "files", "plot", "example", "check")


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["demo", "--help"],
        ["demo", "light-dark", "--help"],
        ["solve", "--help"],
        ["validate", "--help"],
        ["sweep", "--help"],
        ["plot", "--help"],
        ["example", "--help"],
    ],
)
def test_help_everywhere(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_missing_command_and_bad_option_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["demo", "light-dark", "--runs", "0"])
    assert exc.value.code == 2
    assert "--runs" in capsys.readouterr().err


def test_library_error_is_one_line_without_traceback(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    status = main(["demo", "light-dark", "--out", str(blocker), "--runs", "2", "-q"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("idstlpy demo: error:")
    assert "Traceback" not in err


def test_parser_registers_demo():
    parser = build_parser()
    args = parser.parse_args(["demo", "light-dark", "--deadline", "100", "--hold", "10"])
    assert args.deadline == 100 and args.hold == 10 and callable(args.func)


def test_demo_light_dark_writes_its_files(tmp_path, capsys):
    out = tmp_path / "demo"
    status = main(
        ["demo", "light-dark", "--out", str(out), "--runs", "8", "--rrt-timeout", "5", "--seed", "0"]
    )
    captured = capsys.readouterr()
    record = json.loads((out / "result.json").read_text())
    if status == 1:
        raise AssertionError(f"solver found no plan: {record['reason']}")
    assert status == 0, captured.err
    for name in ("plan_execution.png", "monte_carlo.png", "result.json"):
        assert (out / name).stat().st_size > 0
        assert f"wrote {out / name}" in captured.out
    assert "belief success" in captured.out and "state success" in captured.out
    # the result file has the schema of every result file
    assert record["schema"] == "idstlpy.result/1" and record["kind"] == "demo"
    assert record["formula"] == "(free_space U[0,240] G[0,40] target)"
    assert record["problem"]["text"] == (PACKAGE_EXAMPLES / "light_dark.toml").read_text()
    mc = record["validation"]
    assert mc["runs"] == 8 and 0.0 <= mc["belief_success_rate"] <= 1.0
    assert record["status"] == "found" and len(record["plan"]["action"]) > 0
    assert stl.load_result(out / "result.json").found
    assert "Monte Carlo" in captured.err  # progress went to stderr


def test_demo_without_a_plan_writes_null_not_nan(tmp_path, capsys):
    out = tmp_path / "demo"
    status = main(["demo", "light-dark", "--out", str(out), "--deadline", "3", "--hold", "1", "-q"])
    assert status == EXIT_NO_PLAN
    text = (out / "result.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    record = json.loads(text)
    assert record["status"] in ("infeasible", "budget_exhausted") and record["margin"] is None
    assert record["plan"] is None and record["validation"] is None


# ------------------------------------------------------------------------------------------------
# global options, exit codes
# ------------------------------------------------------------------------------------------------


def test_verbose_is_accepted_after_the_subcommand(tmp_path):
    parser = build_parser()
    assert parser.parse_args(["-v", "solve", "f.toml"]).verbose == 1
    assert parser.parse_args(["solve", "f.toml", "-vv"]).verbose == 2
    assert parser.parse_args(["solve", "f.toml"]).verbose == 0
    assert parser.parse_args(["demo", "light-dark", "-v"]).verbose == 1
    assert main(["solve", str(UNSAT), "--out", str(tmp_path), "--quiet", "-v"]) == EXIT_NO_PLAN


def test_exit_codes_are_documented_everywhere(capsys):
    assert (EXIT_OK, EXIT_NO_PLAN, EXIT_USAGE, EXIT_FAILED) == (0, 1, 2, 3)
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "exit status: 0 ok, 1 no plan, 2 usage or input error, 3 a job failed" in capsys.readouterr().out
    for command in ("solve", "validate", "sweep", "plot", "example"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "exit status" in capsys.readouterr().out


def test_scheduler_implies_dask_and_the_dashboard_is_printed(tmp_path, capsys):
    from distributed import LocalCluster

    assert main(["solve", str(UNSAT), "--scheduler", "tcp://h:1", "--executor", "processes"]) == EXIT_USAGE
    assert "--scheduler needs the dask executor" in capsys.readouterr().err
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        code = main(["solve", str(UNSAT), "--out", str(tmp_path), "--scheduler", cluster.scheduler_address])
    out, err = capsys.readouterr()
    assert code == EXIT_NO_PLAN and "dask dashboard: http" in err
    (path,) = tmp_path.glob("*.json")
    assert json.loads(path.read_text())["timing"]["backend"] == "dask"


# ------------------------------------------------------------------------------------------------
# solve --plot, plot, validate --plan
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    out = tmp_path_factory.mktemp("solved")
    figure = out / "plan.svg"
    code = main(
        ["solve", str(LIGHT_DARK), "--out", str(out), "--seed", "1", "--quiet", *FAST, "--plot", str(figure)]
    )
    assert code == EXIT_OK
    (path,) = out.glob("*.json")
    return path, figure


def test_solve_plot_and_the_seed_warning(tmp_path, capsys, solved):
    path, figure = solved
    assert figure.read_text().lstrip().startswith(("<?xml", "<svg"))
    code = main(["solve", str(LIGHT_DARK), "--out", str(tmp_path), *FAST, "--plot", str(tmp_path / "p.pdf")])
    out, err = capsys.readouterr()
    assert code == EXIT_OK and (tmp_path / "p.pdf").read_bytes().startswith(b"%PDF")
    assert "sets no [solver] seed; using the default seed 0" in err
    assert "solving" in err and "(seed 0)" in err and "done" in err  # the elapsed-time line
    record = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert record["seed"] == 0 and record["seed_source"] == "default"
    # the format comes from the extension, checked before solving
    assert main(["solve", str(LIGHT_DARK), "--out", str(tmp_path / "x"), "--plot", "f.gif"]) == EXIT_USAGE
    assert "extension" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_plot_a_result_file(tmp_path, capsys, solved):
    path, _ = solved
    assert main(["plot", str(path), "--out", str(tmp_path / "p.png")]) == EXIT_OK
    assert (tmp_path / "p.png").read_bytes().startswith(b"\x89PNG")
    assert main(["plot", str(path), "--out", str(tmp_path / "q.svg"), "--problem", str(LIGHT_DARK)]) == 0
    # a file saved by SolveResult.save has no problem text: --problem is needed
    bare = stl.SolveResult.from_dict(json.loads(path.read_text()))
    bare.save(tmp_path / "bare.json")
    assert main(["plot", str(tmp_path / "bare.json")]) == EXIT_USAGE
    assert "give the problem file" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "bare.json"), "--problem", str(LIGHT_DARK)]) == EXIT_OK
    assert (tmp_path / "bare.png").exists()
    (tmp_path / "junk.json").write_text('{"a": 1}')
    assert main(["plot", str(tmp_path / "junk.json")]) == EXIT_USAGE
    assert "not an idstlpy result file" in capsys.readouterr().err


def test_plot_kinds_and_one_state_problems(tmp_path, solved):
    path, _ = solved
    assert main(["plot", str(path), "--kind", "time-series", "--out", str(tmp_path / "ts.png")]) == EXIT_OK
    assert (tmp_path / "ts.png").stat().st_size > 0
    one = tmp_path / "one.toml"
    one.write_text(
        'formula = "F[0,10] goal"\n[[modes]]\nA = [[1.0]]\nB = [[1.0]]\nW = [[0.05]]\n[control_domain]\n'
        "low = [-1.0]\nhigh = [1.0]\n[initial_belief]\nmean = [0.0]\ncov = [0.01]\n[propositions.goal]\n"
        'confidence = 0.9\nconstraints = ["2 <= x[0] <= 3"]\n[solver]\nrrt_timeout = 2\nseed = 0\n'
    )
    figure = tmp_path / "one.svg"
    assert (
        main(["solve", str(one), "--out", str(tmp_path / "r"), "--quiet", "--plot", str(figure)]) == EXIT_OK
    )
    assert figure.stat().st_size > 0  # one state: the time series
    (result,) = (tmp_path / "r").glob("*.json")
    assert main(["plot", str(result), "--kind", "workspace"]) == EXIT_USAGE


def test_plot_of_a_result_without_plan(tmp_path):
    assert main(["solve", str(UNSAT), "--out", str(tmp_path), "--quiet"]) == EXIT_NO_PLAN
    (path,) = tmp_path.glob("*.json")
    assert main(["plot", str(path)]) == EXIT_NO_PLAN
    assert path.with_suffix(".png").stat().st_size > 0


def test_validate_a_saved_plan(tmp_path, capsys, solved):
    path, _ = solved
    out = tmp_path / "v"
    code = main(
        ["validate", str(LIGHT_DARK), "--plan", str(path), "--out", str(out), "--set", "validation.runs=4"]
    )
    stdout, err = capsys.readouterr()
    assert code == EXIT_OK, err
    assert "sets no [solver] seed" not in err  # no solving: the solver's seed does not matter
    (rec_path,) = out.glob("*.json")
    record = json.loads(rec_path.read_text())
    assert record["plan_source"] == "saved" and record["check"]["same_problem"] is True
    assert record["plan"] == json.loads(path.read_text())["plan"] and record["validation"]["runs"] == 4
    # a plan of another problem is rejected: exit 1
    # (a hold of 400 steps: no plan of the original problem is that long, whatever the sampler drew)
    stricter = ["--set", 'formula="(free_space U[0,240] G[0,400] target)"']
    assert (
        main(["validate", str(LIGHT_DARK), "--plan", str(path), "--out", str(out), *stricter]) == EXIT_NO_PLAN
    )
    assert "rejected" in capsys.readouterr().out
    # a result without a plan is an input error
    assert main(["solve", str(UNSAT), "--out", str(tmp_path / "u"), "--quiet"]) == EXIT_NO_PLAN
    (unsat,) = (tmp_path / "u").glob("*.json")
    assert main(["validate", str(UNSAT), "--plan", str(unsat), "--out", str(out)]) == EXIT_USAGE
    assert "has no plan" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# shipped examples
# ------------------------------------------------------------------------------------------------


def test_examples_are_shipped_in_the_package_and_mirrored_in_the_repo():
    shipped = sorted(p.name for p in PACKAGE_EXAMPLES.iterdir() if p.suffix in (".toml", ".ipynb"))
    assert {"light_dark.toml", "reach_avoid.toml", "two_modes.toml", "unsatisfiable.toml"} <= set(shipped)
    for name in shipped:
        assert (EXAMPLES / name).read_bytes() == (PACKAGE_EXAMPLES / name).read_bytes(), (
            f"examples/{name} differs from src/idstlpy/examples/{name}: edit the shipped one and copy it"
        )


def test_example_command(tmp_path, capsys):
    assert main(["example", "--list"]) == EXIT_OK
    listing = capsys.readouterr().out
    assert "light-dark" in listing and "unsatisfiable" in listing
    assert main(["example", "light_dark"]) == EXIT_OK
    assert capsys.readouterr().out == (PACKAGE_EXAMPLES / "light_dark.toml").read_text()
    dest = tmp_path / "mine.toml"
    assert main(["example", "two-modes", "--out", str(dest)]) == EXIT_OK
    assert dest.read_text() == (PACKAGE_EXAMPLES / "two_modes.toml").read_text()
    assert main(["example", "two-modes", "--out", str(dest)]) == EXIT_USAGE  # no silent overwrite
    assert "exists" in capsys.readouterr().err
    assert main(["example", "two-modes", "--out", str(dest), "--force"]) == EXIT_OK
    # a sweep comes with the problem file it names
    assert main(["example", "sweep-light-dark", "--out", str(tmp_path)]) == EXIT_OK
    assert (tmp_path / "sweep_light_dark.toml").exists() and (tmp_path / "light_dark.toml").exists()
    from idstlpy.batch import load_sweep

    assert len(load_sweep(tmp_path / "sweep_light_dark.toml").jobs()) == 8
    assert main(["example", "nope"]) == EXIT_USAGE
    assert "no example 'nope'" in capsys.readouterr().err


def test_wheel_ships_the_examples():
    import tomllib

    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    wheel = pyproject["tool"]["hatch"]["build"]["targets"]["wheel"]
    assert "src/idstlpy" in wheel["packages"]  # hatch ships every file of the package: examples too
    assert not any("examples" in e for e in wheel.get("exclude", []))


def test_example_notebook_runs(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    nb = nbformat.read(EXAMPLES / "light_dark.ipynb", as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors, errors
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "status='found'" in text and "belief:" in text
    assert not list(tmp_path.iterdir())  # it writes nothing where it runs


# ------------------------------------------------------------------------------------------------
# docs
# ------------------------------------------------------------------------------------------------

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _options(parser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings if s.startswith("--")}


def test_cli_doc_names_every_command_option_and_exit_status():
    import argparse

    text = (DOCS / "cli.md").read_text()
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for name, command in sub.choices.items():
        assert f"idstlpy {name}" in text, name
        if name == "demo":
            continue
        missing = {
            o for o in _options(command) - {"--help", "--verbose", "--list", "--force"} if o not in text
        }
        assert not missing, f"docs/cli.md does not mention {name} {sorted(missing)}"
    for status in ("| 0 |", "| 1 |", "| 2 |", "| 3 |", "| 130 |"):
        assert status in text
    assert 'if __name__ == "__main__":' in text


def test_results_schema_doc_names_every_field(tmp_path):
    from idstlpy.batch import Job, run_job

    text = (DOCS / "results-schema.md").read_text()
    record = run_job(
        Job.from_file(LIGHT_DARK, "validate", {"solver.rrt_timeout": 5, "validation.runs": 2}, 1)
    )
    missing = [k for k in record if f"`{k}`" not in text]
    missing += [f"plan.{k}" for k in record["plan"] if f"`{k}`" not in text]
    missing += [f"stats.{k}" for k in record["stats"] if f"`{k}`" not in text]
    missing += [f"problem.{k}" for k in record["problem"] if f"`{k}`" not in text]
    assert not missing, f"docs/results-schema.md does not document {missing}"
    assert f'"{record["schema"]}"' in text


def test_sweeps_doc_names_every_key():
    from idstlpy.batch.sweeps import SWEEP_KEYS

    text = (DOCS / "sweeps.md").read_text()
    assert not [k for k in SWEEP_KEYS if f"`{k}`" not in text and f"[{k}]" not in text]


def test_solve_objective_flag_reaches_the_result(tmp_path):
    """`--objective effort` is `--set solver.objective="effort"`: the record says so, proven optimal
    (under the paper's reading: the MLO optimum is predicted to hold in 84% of executions, below
    the default's target, so the default returns a costlier plan it cannot prove optimal)."""
    from idstlpy.cli import main

    problem = tmp_path / "ra.toml"
    assert main(["example", "reach-avoid", "--out", str(problem)]) == 0
    out = tmp_path / "res"
    assert (
        main(
            [
                "solve",
                str(problem),
                "--objective",
                "effort",
                "--guarantee",
                "mlo",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    (record,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert record["status"] == "found" and record["objective"] == "effort"
    assert record["optimal"] and record["objective_value"] > 0


def test_solve_guarantee_flag_reaches_the_result(tmp_path):
    """`--guarantee closed_loop`: the record carries the predicted true state the monitor verified."""
    from idstlpy.cli import main
    from idstlpy.synthesis.results import SolveResult

    problem = tmp_path / "ld.toml"
    assert main(["example", "light-dark", "--out", str(problem)]) == 0
    out = tmp_path / "res"
    assert main(["solve", str(problem), "--guarantee", "closed_loop", "--quiet", "--out", str(out)]) == 0
    (record,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert record["status"] == "found" and record["guarantee"] == "closed_loop"
    result = SolveResult.from_dict(record)
    assert result.predicted is not None
    # The predicted true state is wider than the plan's MLO belief somewhere.
    assert (result.predicted.get_cov() - result.trajectory.get_cov()).max() > 0


def test_python_dash_m_runs_the_command():
    """``python -m idstlpy`` is the command where the venv's scripts are not on PATH."""
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "idstlpy", "--version"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("idstlpy ")
