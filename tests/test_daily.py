"""Daily use: version identity, result equality, the ``plan`` alias and the paper cuts of issue 26."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

import idstlpy
from idstlpy import FormulaSyntaxError, SolveResult, load_problem, load_result, parse_formula
from idstlpy._version import __version__, git_commit, software_info
from idstlpy.batch.records import software_section
from idstlpy.cli.example import example_text
from idstlpy.dynamical_system import LCS, POLBSWithLinNoise, POLBSWithNonLinNoise
from idstlpy.formulas import STLAtomicProposition

ROOT = Path(__file__).resolve().parents[1]
SHA = "0123456789abcdef0123456789abcdef01234567"
SHA2 = "fedcba9876543210fedcba9876543210fedcba98"


@pytest.fixture(scope="module")
def solved() -> SolveResult:
    spec = load_problem(example_text("reach-avoid"), name="reach_avoid.toml")
    problem, kwargs, _ = spec.build()
    result = problem.solve_result(**kwargs)
    assert result.found
    return result


# -- version identity ------------------------------------------------------------------------------


def test_version_is_semantic_and_single_sourced() -> None:
    assert re.fullmatch(r"\d+\.\d+\.\d+", idstlpy.__version__)
    assert idstlpy.__version__ == __version__
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in meta["project"]  # written once, in _version.py
    assert meta["project"]["dynamic"] == ["version"]
    assert meta["tool"]["hatch"]["version"]["path"] == "src/idstlpy/_version.py"


def test_changelog_keeps_an_unreleased_section_and_this_version() -> None:
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in text
    assert f"version {__version__}" in text  # what the code of the Unreleased section reports
    assert text.index("## [Unreleased]") < text.index("## [0.1.0]")


def _fake_checkout(tmp_path: Path) -> Path:
    root = tmp_path / "repo"
    (root / ".git" / "refs" / "heads").mkdir(parents=True)
    return root


def test_git_commit_loose_ref(tmp_path: Path) -> None:
    root = _fake_checkout(tmp_path)
    (root / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    (root / ".git" / "refs" / "heads" / "main").write_text(SHA + "\n")
    assert git_commit(root) == SHA


def test_git_commit_packed_ref_and_detached_head(tmp_path: Path) -> None:
    root = _fake_checkout(tmp_path)
    (root / ".git" / "HEAD").write_text("ref: refs/heads/feature\n")
    (root / ".git" / "packed-refs").write_text(
        f"# pack-refs with: peeled fully-peeled sorted\n{SHA2} refs/heads/feature\n{SHA} refs/tags/v1\n"
    )
    assert git_commit(root) == SHA2
    (root / ".git" / "HEAD").write_text(SHA + "\n")
    assert git_commit(root) == SHA


def test_git_commit_of_a_worktree(tmp_path: Path) -> None:
    main = _fake_checkout(tmp_path)
    (main / ".git" / "refs" / "heads" / "wt").write_text(SHA2 + "\n")
    wt_meta = main / ".git" / "worktrees" / "wt"
    wt_meta.mkdir(parents=True)
    (wt_meta / "HEAD").write_text("ref: refs/heads/wt\n")
    (wt_meta / "commondir").write_text("../..\n")
    wt = tmp_path / "wt"
    wt.mkdir()
    (wt / ".git").write_text(f"gitdir: {wt_meta}\n")
    assert git_commit(wt) == SHA2


@pytest.mark.parametrize(
    "head", [None, "", "ref: refs/heads/missing\n", "not a sha\n", "ref: refs/heads/bad\n"]
)
def test_git_commit_fails_soft(tmp_path: Path, head: str | None) -> None:
    root = _fake_checkout(tmp_path)
    (root / ".git" / "refs" / "heads" / "bad").write_text("xyz\n")
    if head is not None:
        (root / ".git" / "HEAD").write_text(head)
    assert git_commit(root) is None
    assert git_commit(tmp_path / "nowhere") is None
    (tmp_path / "file").write_text("gitdir: /nonexistent/path\n")
    assert git_commit(tmp_path / "file") is None


def test_git_commit_of_this_checkout_without_running_git() -> None:
    commit = git_commit()
    git = shutil.which("git")
    pkg_root = Path(idstlpy.__file__).resolve().parents[2]
    if (pkg_root / ".git").exists() and git is not None:
        expected = subprocess.run(
            [git, "-C", str(pkg_root), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        assert commit == expected
    else:  # an installed copy: no checkout, no commit
        assert commit is None


def test_software_info_is_what_records_and_results_carry(solved: SolveResult) -> None:
    info = software_info()
    assert info["idstlpy"] == __version__
    assert set(info) == {"idstlpy", "commit", "python", "numpy", "platform"}
    assert software_section() == info
    assert solved.software == info
    assert solved.version == __version__
    assert solved.commit == info["commit"]
    assert solved.to_dict()["software"] == info


def test_saved_result_keeps_the_software_that_made_it(tmp_path: Path, solved: SolveResult) -> None:
    data = solved.to_dict()
    data["software"] = {**data["software"], "idstlpy": "0.0.9", "commit": SHA}
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    old = load_result(path)
    assert old.version == "0.0.9"
    assert old.commit == SHA
    # a file written before the field existed
    del data["software"]
    path.write_text(json.dumps(data))
    older = load_result(path)
    assert older.software == {}
    assert older.version is None and older.commit is None


# -- SolveResult: plan alias and equality -----------------------------------------------------------


def test_plan_is_the_trajectory(solved: SolveResult) -> None:
    assert solved.plan is solved.trajectory
    assert "plan" in solved.to_dict()
    assert SolveResult("infeasible", None, "r").plan is None


def test_round_trip_is_equal(tmp_path: Path, solved: SolveResult) -> None:
    path = solved.save(tmp_path / "r.json")
    loaded = load_result(path)
    assert loaded == solved
    assert not (loaded != solved)
    assert loaded.to_dict() == solved.to_dict()


def test_equality_compares_values(tmp_path: Path, solved: SolveResult) -> None:
    loaded = load_result(solved.save(tmp_path / "r.json"))
    # NaN fields (objective_value, objective_bound) compare equal to NaN
    assert np.isnan(solved.objective_bound) and loaded == solved
    other = load_result(solved.save(tmp_path / "r2.json"))
    other.margin = solved.margin + 1e-12
    assert other != solved
    other = load_result(solved.save(tmp_path / "r3.json"))
    assert other.trajectory is not None
    controls = other.trajectory.get_control().copy()
    controls[0, 0] += 1e-9
    changed = type(other.trajectory)(
        other.trajectory.get_mean(), other.trajectory.get_cov(), other.trajectory.get_action(), controls
    )
    other.trajectory = changed
    assert other != solved
    other = load_result(solved.save(tmp_path / "r4.json"))
    other.stats.candidates += 1
    assert other != solved
    assert solved != "found"
    assert SolveResult("infeasible", None, "r") == SolveResult("infeasible", None, "r")
    assert SolveResult("infeasible", None, "r") != SolveResult("found", None, "r")
    assert solved != SolveResult(solved.status, None, solved.reason)


# -- paper cuts -------------------------------------------------------------------------------------


def test_dir_shows_no_module_plumbing() -> None:
    names = dir(idstlpy)
    assert "annotations" not in names
    assert "logging" not in names
    assert "__version__" in names


def test_binary_temporal_operator_without_parentheses_says_so() -> None:
    atoms = {name: STLAtomicProposition() for name in ("safe", "goal", "a", "b", "c")}
    with pytest.raises(
        FormulaSyntaxError, match=re.escape("binary temporal operators need parentheses: (safe U[0,40] goal)")
    ):
        parse_formula("safe U[0,40] goal", atoms)
    with pytest.raises(FormulaSyntaxError, match=re.escape("binary operators need parentheses: (a & b)")):
        parse_formula("a & b", atoms)
    with pytest.raises(FormulaSyntaxError, match="binary temporal operators need parentheses"):
        parse_formula("(a & b U[0,3] c)", atoms)
    with pytest.raises(FormulaSyntaxError, match="binary temporal operators need parentheses"):
        parse_formula("G[0,3] a R[0,2] b", atoms)
    # the parenthesised formula is accepted
    assert str(parse_formula("(safe U[0,40] goal)", atoms)).count("U[0,40]") == 1


@pytest.mark.parametrize("cls", [LCS, POLBSWithLinNoise, POLBSWithNonLinNoise])
def test_noise_methods_have_docstrings(cls: type) -> None:
    for name in ("noise", "noise_cov", "noise_floor", "has_state_dependent_noise"):
        member = cls.__dict__.get(name)
        if member is None:  # inherited: the base class documents it
            continue
        doc = (member.fget if isinstance(member, property) else member).__doc__
        assert doc and doc.strip(), f"{cls.__name__}.{name} has no docstring"


def test_plot_help_names_problem(capsys: pytest.CaptureFixture[str]) -> None:
    from idstlpy.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["plot", "--help"])
    assert exc.value.code == 0
    assert "--problem" in capsys.readouterr().out


def _make_dry_run(tmp_path: Path, make: str, target: str) -> str:
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    (tmp_path / "pyproject.toml").write_text("")
    out = subprocess.run([make, "-n", target], cwd=tmp_path, capture_output=True, text=True, check=True)
    return out.stdout


def test_make_demo_does_not_install_the_test_toolchain(tmp_path: Path) -> None:
    make = shutil.which("make")
    if make is None:  # read the demo stamp's recipe instead
        text = (ROOT / "Makefile").read_text()
        demo_stamp = re.search(r"^\$\(DEMO_STAMP\):.*\n((?:\t.*\n)+)", text, re.M)
        assert demo_stamp is not None and "[test]" not in demo_stamp.group(1)
        return
    demo = _make_dry_run(tmp_path, make, "demo")
    assert "pip install" in demo and "-e ." in demo
    assert "[test]" not in demo
    assert "idstlpy demo light-dark" in demo
    test = _make_dry_run(tmp_path, make, "test")
    assert "[test]" in test


def test_version_option_names_the_version_and_the_commit(capsys: pytest.CaptureFixture[str]) -> None:
    from idstlpy.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out.strip()
    commit = git_commit()
    assert out == f"idstlpy {__version__}" + (f" (commit {commit[:12]})" if commit else "")


def test_batch_records_carry_the_version_and_the_commit(tmp_path: Path) -> None:
    from idstlpy.batch.jobs import Job, run_job

    record = run_job(Job("solve", example_text("reach-avoid"), "reach_avoid.toml"))
    assert record["status"] == "found"
    assert record["software"] == software_info()
    assert record["software"]["idstlpy"] == __version__
    assert record["software"]["commit"] == git_commit()
    # a saved plan validated later: the record names the code that validated it
    saved = dict(record)
    saved["software"] = {**record["software"], "idstlpy": "0.0.1", "commit": SHA}
    job = Job("validate", example_text("reach-avoid"), "reach_avoid.toml", {"validation.runs": 4}, plan=saved)
    checked = run_job(job)
    assert checked["status"] == "found" and checked["plan_source"] == "saved"
    assert checked["software"] == software_info()
    # SolveResult.save writes the same field, load_result reads it back
    result = SolveResult.from_dict(record)
    assert result.software == software_info()
    assert load_result(result.save(tmp_path / "r.json")) == result
