"""The ``idstlpy`` command: help everywhere, one-line errors, and the light-dark demo end to end."""

from __future__ import annotations

import json

import pytest

from idstlpy.cli import _COMMAND_MODULES, build_parser, main


def test_command_modules_tuple():
    assert _COMMAND_MODULES[:2] == ("demo", "files")


@pytest.mark.parametrize("argv", [["--help"], ["demo", "--help"], ["demo", "light-dark", "--help"]])
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
    summary = json.loads((out / "summary.json").read_text())
    if status == 1:
        raise AssertionError(f"solver found no plan: {summary['solve']['reason']}")
    assert status == 0, captured.err
    for name in ("plan_execution.png", "monte_carlo.png", "summary.json"):
        assert (out / name).stat().st_size > 0
        assert f"wrote {out / name}" in captured.out
    assert "belief success" in captured.out and "state success" in captured.out
    mc = summary["monte_carlo"]
    assert mc["runs"] == 8 and 0.0 <= mc["belief_success_rate"] <= 1.0
    assert summary["solve"]["status"] == "found" and summary["plan"]["num_of_steps"] > 0
    assert "Monte Carlo" in captured.err  # progress went to stderr
