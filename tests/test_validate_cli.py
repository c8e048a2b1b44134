"""``idstlpy validate``: the true start it used, its verdict against the execution target, exit 4."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from idstlpy.cli import EXIT_BELOW_TARGET, EXIT_OK, EXIT_USAGE, main
from idstlpy.cli.exit_codes import exit_status
from idstlpy.problem_file import load_problem

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
REACH_AVOID = EXAMPLES / "reach_avoid.toml"  # noise-free: every run succeeds


def _record(out: Path) -> dict:
    (path,) = out.glob("*.json")
    return json.loads(path.read_text())


def test_prior_start_and_verdict_are_printed_and_recorded(tmp_path, capsys):
    out = tmp_path / "ok"
    assert main(["validate", str(REACH_AVOID), "--out", str(out), "--quiet"]) == EXIT_OK
    stdout = capsys.readouterr().out
    assert "true start: drawn from the prior (every run its own)" in stdout
    assert "verdict: meets the target (90% belief / 95% true state)" in stdout
    validation = _record(out)["validation"]
    assert validation["true_start"] == "prior"
    assert validation["execution_target"] == {"belief": 0.9, "state": 0.95}
    assert validation["meets_target"] is True


def test_below_target_exits_4(tmp_path, capsys):
    # a fixed true start far off the plan: the clipped inputs cannot bring it to the goal in time
    far = ["--set", "execution.real_initial_state=[-4.0, 0.0]", "--target", "0.5,0.5"]
    out = tmp_path / "far"
    assert main(["validate", str(REACH_AVOID), "--out", str(out), "--quiet", *far]) == EXIT_BELOW_TARGET
    stdout = capsys.readouterr().out
    assert "true start: fixed at [-4, 0]" in stdout
    assert "verdict: BELOW the target (50% belief / 50% true state)" in stdout
    validation = _record(out)["validation"]
    assert validation["true_start"] == [-4.0, 0.0]
    assert validation["execution_target"] == {"belief": 0.5, "state": 0.5}
    assert validation["meets_target"] is False


def test_target_option_and_file_key_are_checked(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["validate", str(REACH_AVOID), "--target", "0.9"])
    assert exc.value.code == EXIT_USAGE
    assert "BELIEF,STATE" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["validate", str(REACH_AVOID), "--target", "0.9,1.2"])
    capsys.readouterr()
    bad = ["--set", "validation.execution_target=[0.9]", "--out", str(tmp_path / "bad")]
    assert main(["validate", str(REACH_AVOID), *bad]) == EXIT_USAGE
    assert "execution_target" in capsys.readouterr().err


def test_file_key_sets_the_target():
    text = REACH_AVOID.read_text().replace("[validation]\n", "[validation]\nexecution_target = [0.8, 0.85]\n")
    execution = load_problem(text, name="t.toml").build().execution
    assert execution.execution_target is not None
    assert execution.execution_target.as_dict() == {"belief": 0.8, "state": 0.85}
    assert execution.real_initial_state is None  # not given: drawn from the prior


def test_exit_status_order():
    found_ok = {"status": "found", "validation": {"meets_target": True}}
    found_short = {"status": "found", "validation": {"meets_target": False}}
    assert exit_status([found_ok]) == EXIT_OK
    assert exit_status([found_ok, found_short]) == EXIT_BELOW_TARGET
    assert exit_status([found_short, {"status": "infeasible"}]) == 1
    assert exit_status([found_short, {"status": "error"}]) == 3
    assert exit_status([{"status": "found", "validation": None}]) == EXIT_OK
