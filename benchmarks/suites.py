"""The benchmark suites: which jobs to run, repeats, medians and skip rules.

Each suite yields result rows (dicts) with the median ``build_s`` / ``solve_s`` / ``e2e_s`` over
its repeats, the status of every repeat, and the verification evidence of the first solved run.
A run that times out is not repeated; a tool that timed out (or was killed) on a scenario at
horizon ``T`` is not run at larger horizons of that scenario (reported as ``not_run``).
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from .catalogue import SCENARIOS
from .harness import Worker

__all__ = ["Config", "run_stlpy_suite", "run_prstl_suite", "run_light_dark_suite", "load_rows"]

logger = logging.getLogger(__name__)

PEERS = ("gurobi", "highs", "scip")
MODES = ("feasibility", "robustness")
HORIZONS = (25, 50, 100, 200)


@dataclass
class Config:
    """Options shared by the suites."""

    repeats: int = 3
    timeout: float = 60.0
    grace: float = 30.0
    scenarios: tuple[str, ...] = tuple(SCENARIOS)
    horizons: tuple[int, ...] = HORIZONS
    include_example_T: bool = True
    peers: tuple[str, ...] = PEERS
    modes: tuple[str, ...] = MODES
    skip_after_timeout: bool = True
    prstl_horizons: tuple[int, ...] = (25, 50, 100)
    light_dark_seeds: int = 10
    light_dark_time_limit: float | None = None  # None: idstlpy's default, 10 * rrt_timeout
    threads: int = 0
    run_idstlpy: bool = True
    run_peers: bool = True
    extra: dict[str, Any] = field(default_factory=dict)


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def _repeat(worker: Worker, target: str, kwargs: dict[str, Any], cfg: Config, hard: float) -> dict[str, Any]:
    """Run a job up to ``cfg.repeats`` times; summarise as one row."""
    runs: list[dict[str, Any]] = []
    for _ in range(cfg.repeats):
        out = worker.run(target, kwargs, hard)
        runs.append(out)
        if out.get("status") != "solved":
            break  # a timeout / failure is not repeated
    statuses = [r.get("status", "error") for r in runs]
    solved = [r for r in runs if r.get("status") == "solved"]
    pick = solved if solved and len(solved) == len(runs) else runs
    row: dict[str, Any] = {
        "status": statuses[0] if len(set(statuses)) == 1 else f"mixed({'/'.join(statuses)})",
        "repeats": len(runs),
        "build_s": _median([r["build_s"] for r in pick if "build_s" in r]),
        "solve_s": _median([r["solve_s"] for r in pick if "solve_s" in r]),
        "e2e_s": _median([r["e2e_s"] for r in pick if "e2e_s" in r]),
        "e2e_runs": ";".join(f"{r.get('e2e_s', float('nan')):.4g}" for r in runs),
    }
    first = solved[0] if solved else runs[0]
    for key, val in first.items():
        if key not in row and key != "traceback":
            row[key] = val
    if not solved:
        row.setdefault("verified", "")
    if "traceback" in first:
        logger.warning("%s %s failed:\n%s", target, kwargs, first["traceback"])
    return row


def _horizons(name: str, cfg: Config) -> list[int]:
    hs = list(cfg.horizons)
    if cfg.include_example_T:
        hs.append(SCENARIOS[name].example_T)
    return sorted(set(hs))


def run_stlpy_suite(worker: Worker, cfg: Config) -> Iterator[dict[str, Any]]:
    """Suites (a) and (b): stlpy's scenarios through idstlpy and stlpy's MICP, side by side."""
    tools: list[tuple[str, str, str]] = []
    if cfg.run_idstlpy:
        tools.append(("idstlpy", "-", "benchmarks.peers:idstlpy_stlpy"))
    for mode in cfg.modes if cfg.run_peers else ():
        for peer in cfg.peers:
            tools.append((f"stlpy+{peer}", mode, "benchmarks.peers:stlpy_micp"))
    hard = cfg.timeout + cfg.grace
    for name in cfg.scenarios:
        failed_at: dict[tuple[str, str], int] = {}
        for T in _horizons(name, cfg):
            timed_out: list[tuple[str, str]] = []
            infeasible = any(
                r.get("status") == "infeasible"
                for r in cfg.extra.get("known", [])
                if r.get("scenario") == name and r.get("T") == T
            )
            for tool, mode, target in tools:
                base = {
                    "suite": "stlpy",
                    "scenario": name,
                    "T": T,
                    "tool": tool,
                    "mode": mode,
                    "example_T": SCENARIOS[name].example_T,
                }
                if cfg.skip_after_timeout and (tool, mode) in failed_at:
                    yield {
                        **base,
                        "status": "not_run",
                        "repeats": 0,
                        "detail": f"timed out at T = {failed_at[(tool, mode)]}",
                    }
                    continue
                if tool == "idstlpy":
                    kwargs = {"name": name, "T": T, "time_limit": cfg.timeout}
                else:
                    kwargs = {
                        "name": name,
                        "T": T,
                        "backend": tool.split("+")[1],
                        "mode": mode,
                        "time_limit": cfg.timeout,
                        "threads": cfg.threads,
                    }
                t0 = time.perf_counter()
                row = {**base, **_repeat(worker, target, kwargs, cfg, hard)}
                logger.info(
                    "%-18s T=%-4d %-14s %-12s %-10s e2e %8.3f s  (%.1f s wall)",
                    name,
                    T,
                    tool,
                    mode,
                    row["status"],
                    row.get("e2e_s", float("nan")),
                    time.perf_counter() - t0,
                )
                if row["status"] in ("timeout", "killed"):
                    timed_out.append((tool, mode))
                if row["status"] == "infeasible":
                    infeasible = True
                yield row
            # A timeout on an instance some tool proved infeasible says nothing about larger T
            # (DoorPuzzle is infeasible at T = 25 and feasible at T = 30).
            if not infeasible:
                for key in timed_out:
                    failed_at[key] = T


def run_prstl_suite(worker: Worker, cfg: Config) -> Iterator[dict[str, Any]]:
    """Suite (c): noisy reach-avoid, idstlpy vs the hand-written chance-constrained MILP."""
    hard = cfg.timeout + cfg.grace
    failed: set[str] = set()
    for T in cfg.prstl_horizons:
        jobs = []
        if cfg.run_idstlpy:
            jobs.append(("idstlpy", "benchmarks.peers:idstlpy_prstl", {"T": T, "time_limit": cfg.timeout}))
        if cfg.run_peers:
            jobs.append(("cc-milp+highs", "benchmarks.peers:milp_prstl", {"T": T, "time_limit": cfg.timeout}))
        for tool, target, kwargs in jobs:
            base = {
                "suite": "prstl",
                "scenario": "NoisyReachAvoid",
                "T": T,
                "tool": tool,
                "mode": "feasibility",
            }
            if cfg.skip_after_timeout and tool in failed:
                yield {**base, "status": "not_run", "repeats": 0, "detail": "timed out at a smaller T"}
                continue
            row = {**base, **_repeat(worker, target, kwargs, cfg, hard)}
            logger.info(
                "NoisyReachAvoid    T=%-4d %-14s %-10s e2e %8.3f s",
                T,
                tool,
                row["status"],
                row.get("e2e_s", float("nan")),
            )
            if row["status"] in ("timeout", "killed"):
                failed.add(tool)
            yield row


def run_light_dark_suite(worker: Worker, cfg: Config) -> Iterator[dict[str, Any]]:
    """Suite (d): the light-dark listing over seeds, and its horizon-stretched variant."""
    if not cfg.run_idstlpy:
        return
    limit = cfg.light_dark_time_limit
    hard = (limit if limit is not None else 600.0) + cfg.grace
    for variant, deadline, hold in [("listing", 240, 40), ("stretched", 960, 160)]:
        for seed in range(cfg.light_dark_seeds):
            out = worker.run(
                "benchmarks.peers:idstlpy_light_dark",
                {"seed": seed, "deadline": deadline, "hold": hold, "time_limit": limit},
                hard,
            )
            row = {
                "suite": "light_dark",
                "scenario": f"light_dark[{variant}]",
                "T": deadline + hold,
                "tool": "idstlpy",
                "mode": f"seed={seed}",
                "repeats": 1,
            }
            row.update({k: v for k, v in out.items() if k != "traceback"})
            logger.info(
                "light_dark %-9s seed %d: %s in %.3f s",
                variant,
                seed,
                row.get("status"),
                row.get("e2e_s", float("nan")),
            )
            yield row


_FLOATS = (
    "build_s",
    "solve_s",
    "e2e_s",
    "stlpy_robustness",
    "margin",
    "dyn_residual",
    "box_violation",
    "time_bmc",
    "time_lp",
)


def load_rows(path: str, keep_tools: str) -> list[dict[str, Any]]:
    """Rows of an earlier ``results.csv``.

    ``keep_tools`` is ``peers`` (every tool but idstlpy, marked as reused), ``idstlpy`` or
    ``all``.
    """
    import csv

    out = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            is_ido = r["tool"] == "idstlpy"
            if (keep_tools == "peers" and is_ido) or (keep_tools == "idstlpy" and not is_ido):
                continue
            row: dict[str, Any] = {k: v for k, v in r.items() if v != ""}
            row["T"] = int(row["T"])
            for k in _FLOATS:
                if k in row:
                    row[k] = float(row[k])
            if keep_tools == "peers":
                row["reused_from"] = path
            out.append(row)
    return out
