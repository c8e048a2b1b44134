"""Entry point: ``python -m benchmarks [--suites ...] [--quick] [--out DIR]``.

Suites: ``stlpy`` (stlpy's scenarios through idstlpy and stlpy's MICP on Gurobi / HiGHS / SCIP,
side by side), ``prstl`` (noisy reach-avoid vs a chance-constrained MILP), ``lightdark`` (the
paper's example over seeds, and its stretched horizon). Writes ``results.csv``,
``results.md`` and ``horizon_scaling.png`` into ``--out`` (default ``results/``) and, unless
``--quick`` or ``--no-doc``, refreshes ``BENCHMARKS.md`` at the repository root and keeps a copy of
the CSV and the plot it shows under ``benchmarks/results/``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import os
import shutil
import sys
import time
from pathlib import Path

from .catalogue import SCENARIOS
from .harness import Worker
from .report import command_line, machine, markdown, plot_scaling, write_benchmarks_md, write_csv
from .suites import (
    HORIZONS,
    MODES,
    PEERS,
    Config,
    load_rows,
    run_light_dark_suite,
    run_prstl_suite,
    run_stlpy_suite,
)

ROOT = Path(__file__).resolve().parent.parent
ALL_SUITES = ("stlpy", "prstl", "lightdark")


def _csv_list(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--suites",
        type=_csv_list,
        default=ALL_SUITES,
        help=f"comma-separated subset of {','.join(ALL_SUITES)} (default: all)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="small subset: 3 scenarios at their example T and T=25, 1 repeat, 20 s limit, "
        "PrSTL at T=25, 3 light-dark seeds; does not touch BENCHMARKS.md",
    )
    p.add_argument(
        "--scenarios",
        type=_csv_list,
        default=None,
        help=f"stlpy scenarios (default: all of {','.join(SCENARIOS)})",
    )
    p.add_argument(
        "--horizons",
        type=lambda s: tuple(int(x) for x in _csv_list(s)),
        default=None,
        help=f"horizons T besides each example's own (default: {','.join(map(str, HORIZONS))})",
    )
    p.add_argument("--no-example-T", action="store_true", help="do not add each scenario's example T")
    p.add_argument("--peers", type=_csv_list, default=PEERS, help="subset of gurobi,highs,scip")
    p.add_argument("--modes", type=_csv_list, default=MODES, help="subset of feasibility,robustness")
    p.add_argument("--repeats", type=int, default=None, help="repeats per job (default 3; median)")
    p.add_argument("--timeout", type=float, default=None, help="time limit per run in seconds (default 60)")
    p.add_argument(
        "--no-skip",
        action="store_true",
        help="run larger horizons even after a tool timed out on a smaller one",
    )
    p.add_argument("--prstl-horizons", type=lambda s: tuple(int(x) for x in _csv_list(s)), default=None)
    p.add_argument("--light-dark-seeds", type=int, default=None)
    p.add_argument(
        "--only", choices=("idstlpy", "peers"), default=None, help="run only idstlpy or only the peers"
    )
    p.add_argument(
        "--reuse-peers",
        type=Path,
        default=None,
        metavar="CSV",
        help="take the peers' rows from an earlier results.csv and run idstlpy only "
        "(the peers do not change when idstlpy does)",
    )
    p.add_argument("--threads", type=int, default=0, help="solver threads for the peers (0: their default)")
    p.add_argument("--out", type=Path, default=ROOT / "results", help="output directory (default results/)")
    p.add_argument("--no-doc", action="store_true", help="do not rewrite BENCHMARKS.md")
    p.add_argument("--doc", type=Path, default=ROOT / "BENCHMARKS.md", help="where to write BENCHMARKS.md")
    p.add_argument(
        "--doc-from",
        type=Path,
        default=None,
        metavar="DIR",
        help="run nothing: refresh BENCHMARKS.md's sections from an earlier run's --out DIR "
        "(its results.csv and run.json), e.g. after editing benchmarks/analysis.md",
    )
    p.add_argument("-v", "--verbose", action="store_true")
    return p.parse_args(argv)


def make_config(a: argparse.Namespace) -> Config:
    cfg = Config()
    if a.quick:
        cfg.repeats, cfg.timeout = 1, 20.0
        cfg.scenarios = ("ReachAvoid", "EitherOr", "NarrowPassage")
        cfg.horizons = (25,)
        cfg.prstl_horizons = (25,)
        cfg.light_dark_seeds = 3
    if a.scenarios is not None:
        unknown = set(a.scenarios) - set(SCENARIOS)
        if unknown:
            raise SystemExit(f"unknown scenarios {sorted(unknown)}; choose from {list(SCENARIOS)}")
        cfg.scenarios = a.scenarios
    if a.horizons is not None:
        cfg.horizons = a.horizons
    if a.repeats is not None:
        cfg.repeats = a.repeats
    if a.timeout is not None:
        cfg.timeout = a.timeout
    if a.prstl_horizons is not None:
        cfg.prstl_horizons = a.prstl_horizons
    if a.light_dark_seeds is not None:
        cfg.light_dark_seeds = a.light_dark_seeds
    cfg.include_example_T = not a.no_example_T
    cfg.peers, cfg.modes = a.peers, a.modes
    cfg.skip_after_timeout = not a.no_skip
    cfg.threads = a.threads
    if a.only == "idstlpy" or a.reuse_peers is not None:
        cfg.run_peers = False
    if a.only == "peers":
        cfg.run_idstlpy = False
    return cfg


def _load() -> str:
    """The 1-minute load average (other jobs on the machine inflate every tool's seconds)."""
    return f"{os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else "?"


def _write_doc(a: argparse.Namespace, run: dict, tables: str, plotted: bool, png_path: Path) -> None:
    """Refresh BENCHMARKS.md's runner sections (the other sections are kept, see report.py)."""
    analysis_file = Path(__file__).with_name("analysis.md")
    analysis = analysis_file.read_text() if analysis_file.exists() else None
    try:
        plot_rel = str(png_path.relative_to(a.doc.resolve().parent)) if plotted else None
    except ValueError:
        plot_rel = str(png_path) if plotted else None
    write_benchmarks_md(
        a.doc,
        tables,
        run["command"],
        run["machine"],
        run["timeout"],
        run["repeats"],
        plot_rel,
        run["started"],
        run["wall"],
        analysis,
        run.get("load"),
        run.get("suites"),
    )
    logging.info("wrote %s", a.doc)


def _doc_from(a: argparse.Namespace) -> int:
    """``--doc-from DIR``: re-render the tables of an earlier run and refresh BENCHMARKS.md."""
    run = json.loads((a.doc_from / "run.json").read_text())
    rows = load_rows(str(a.doc_from / "results.csv"), "all")
    tables = markdown(rows, run["timeout"], run["peers"], run["modes"])
    kept = ROOT / "benchmarks" / "results"
    kept.mkdir(exist_ok=True)
    for name in ("results.csv", "run.json", "horizon_scaling.png"):
        src = a.doc_from / name
        if src.exists() and src.resolve() != (kept / name).resolve():
            shutil.copy(src, kept / name)
    png = kept / "horizon_scaling.png"
    _write_doc(a, run, tables, png.exists(), png)
    return 0


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if a.verbose else logging.INFO,
        format="%(asctime)s %(message)s",
        datefmt="%H:%M:%S",
    )
    for name in ("matplotlib", "PIL", "idstlpy"):
        logging.getLogger(name).setLevel(logging.WARNING)
    if a.doc_from is not None:
        return _doc_from(a)
    cfg = make_config(a)
    unknown = set(a.suites) - set(ALL_SUITES)
    if unknown:
        raise SystemExit(f"unknown suites {sorted(unknown)}; choose from {list(ALL_SUITES)}")
    a.out.mkdir(parents=True, exist_ok=True)
    started = dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    load0 = _load()
    t0 = time.perf_counter()
    rows: list[dict] = []
    if a.reuse_peers is not None:
        rows.extend(
            r
            for r in load_rows(str(a.reuse_peers), "peers")
            if r["suite"] in a.suites and (r["suite"] != "stlpy" or r["scenario"] in cfg.scenarios)
        )
        logging.info("reusing %d peer rows from %s", len(rows), a.reuse_peers)
        cfg.extra["known"] = list(rows)
    csv_path, md_path, png_path = a.out / "results.csv", a.out / "results.md", a.out / "horizon_scaling.png"
    with Worker() as worker:
        for suite, runner in (
            ("stlpy", run_stlpy_suite),
            ("prstl", run_prstl_suite),
            ("lightdark", run_light_dark_suite),
        ):
            if suite not in a.suites:
                continue
            for row in runner(worker, cfg):
                rows.append(row)
                write_csv(rows, csv_path)  # keep partial results if interrupted
    wall = time.perf_counter() - t0
    tables = markdown(rows, cfg.timeout, cfg.peers, cfg.modes)
    mach = machine()
    plotted = plot_scaling(rows, png_path, cfg.timeout)
    cmd = command_line()
    md_path.write_text(
        f"# Benchmark results\n\n`{cmd}` - {started}, nproc {mach['nproc']}, {mach['cpu']}\n\n{tables}\n"
    )
    run = {
        "command": cmd,
        "started": started,
        "wall": wall,
        "machine": mach,
        "timeout": cfg.timeout,
        "repeats": cfg.repeats,
        "peers": list(cfg.peers),
        "modes": list(cfg.modes),
        "load": f"{load0} at the start, {_load()} at the end",
        "suites": list(a.suites),
    }
    (a.out / "run.json").write_text(json.dumps(run, indent=1))
    logging.info("wrote %s, %s%s", csv_path, md_path, f", {png_path}" if plotted else "")
    if not a.quick and not a.no_doc:
        # results/ is scratch (git-ignored); the figures BENCHMARKS.md shows are kept beside the code.
        kept = ROOT / "benchmarks" / "results"
        kept.mkdir(exist_ok=True)
        shutil.copy(csv_path, kept / "results.csv")
        shutil.copy(a.out / "run.json", kept / "run.json")
        if plotted:
            png_path = Path(shutil.copy(png_path, kept / "horizon_scaling.png"))
        _write_doc(a, run, tables, plotted, png_path)
    print(tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
