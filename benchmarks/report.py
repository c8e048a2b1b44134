"""CSV, Markdown tables, the horizon-scaling plot and BENCHMARKS.md."""

from __future__ import annotations

import csv
import math
import os
import platform
import subprocess
import sys
from collections import defaultdict
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = ["machine", "write_csv", "markdown", "plot_scaling", "write_benchmarks_md", "merge_benchmarks_md"]

CSV_FIELDS = [
    "suite",
    "scenario",
    "T",
    "tool",
    "mode",
    "status",
    "verified",
    "repeats",
    "build_s",
    "solve_s",
    "e2e_s",
    "e2e_runs",
    "stlpy_robustness",
    "monitor",
    "margin",
    "dyn_residual",
    "box_violation",
    "nvars",
    "ncons",
    "nbin",
    "candidates",
    "counterexamples",
    "bmc_depth",
    "time_bmc",
    "time_lp",
    "plan_steps",
    "translation",
    "detail",
]


def machine() -> dict[str, str]:
    """nproc, CPU model (from /proc/cpuinfo), Python and package versions, git revision."""
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    versions = []
    for pkg in ("idstlpy", "stlpy", "gurobipy", "highspy", "pyscipopt", "scipy", "numpy", "python-sat"):
        try:
            versions.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{pkg} (missing)")
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent,
            check=False,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "src"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent,
            check=False,
        ).stdout.strip()
        rev = (rev + (" + uncommitted changes in src/" if dirty else "")) or "unknown"
    except OSError:
        rev = "unknown"
    snapshot = os.environ.get("IDSTLPY_COMMIT", "").strip()
    if snapshot and (not rev or rev == "unknown"):
        # Run from a `git archive` snapshot, which is no repository: the caller names its commit.
        rev = f"{snapshot} (run from a snapshot of that commit, `git archive`)"
    return {
        "nproc": str(os.cpu_count()),
        "cpu": cpu,
        "python": f"{platform.python_implementation()} {platform.python_version()}",
        "platform": platform.platform(),
        "packages": ", ".join(versions),
        "git": rev,
    }


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    extra = sorted({k for r in rows for k in r} - set(CSV_FIELDS))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS + extra, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _csv_val(r.get(k, "")) for k in CSV_FIELDS + extra})


def _csv_val(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def _t(x: Any) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    x = float(x)
    return f"{x:.3f}" if x < 10 else f"{x:.1f}"


def _cell(row: dict[str, Any] | None, timeout: float) -> str:
    """One table cell: time when solved, else the failure, with verification marks."""
    if row is None:
        return "-"
    st = row.get("status", "")
    if st == "solved":
        mark = "" if row.get("verified") in (True, "True") else " (UNVERIFIED)"
        return f"{_t(row.get('e2e_s'))}{mark}"
    if st in ("timeout", "killed"):
        inc = " (incumbent)" if row.get("verified") in (True, "True") else ""
        return f"timeout >{timeout:g}{inc}"
    if st == "not_run":
        d = str(row.get("detail", ""))
        if "licence" in d:
            return f"n/a: licence ({row.get('nvars')} vars)"
        return f"skipped ({d})"
    if st == "infeasible":
        return "infeasible"
    return st


def _ratio(ido: dict[str, Any] | None, peer: dict[str, Any] | None, timeout: float) -> str:
    """``idstlpy e2e / peer e2e`` (bounds when one side timed out)."""
    if ido is None or peer is None:
        return "-"
    a_ok, b_ok = ido.get("status") == "solved", peer.get("status") == "solved"
    a, b = ido.get("e2e_s"), peer.get("e2e_s")
    if a_ok and b_ok:
        return f"{a / b:.3g}"
    if a_ok and peer.get("status") in ("timeout", "killed"):
        return f"<{a / timeout:.3g}"
    if b_ok and ido.get("status") in ("timeout", "killed", "not_run"):
        return f">{timeout / b:.3g}"
    return "-"


def _index(rows: Sequence[dict[str, Any]]) -> dict[tuple, dict[str, Any]]:
    return {(r["suite"], r["scenario"], r["T"], r["tool"], r["mode"]): r for r in rows}


def markdown(
    rows: Sequence[dict[str, Any]], timeout: float, peers: Sequence[str], modes: Sequence[str]
) -> str:
    """The Markdown tables of every suite present in ``rows``."""
    out: list[str] = []
    idx = _index(rows)
    digests = sorted({str(r["idstlpy_src"]) for r in rows if r.get("idstlpy_src")})
    if digests:
        out.append(
            f"idstlpy sources measured (sha1 prefix of `src/idstlpy/**/*.py` as loaded by the "
            f"worker): {', '.join(digests)}\n"
        )
    reused = sorted({str(r["reused_from"]) for r in rows if r.get("reused_from")})
    if reused:
        out.append(
            f"Peer rows reused from an earlier run: {', '.join(reused)} (same machine; the "
            "peers do not depend on idstlpy's code).\n"
        )
    st = [r for r in rows if r["suite"] == "stlpy"]
    if st:
        keys = sorted({(r["scenario"], r["T"]) for r in st}, key=lambda k: (_order(k[0]), k[1]))
        out.append("### stlpy scenarios: end-to-end seconds (median of repeats)\n")
        out.append(
            "Cells: end-to-end time (specification + encoding + solve) in seconds; "
            "`timeout >L` = no answer within the limit; `(incumbent)` = a verified solution was "
            "found but optimality not proven. `UNVERIFIED` would flag a solution rejected by "
            "stlpy's robustness or idstlpy's monitor.\n"
        )
        cols = [(f"stlpy+{p}", m) for m in modes for p in peers]
        head = ["scenario", "T", "idstlpy", "idstlpy verified"]
        head += [f"{t.split('+')[1]} {m[:4]}" for t, m in cols]
        head += ["idstlpy / best open (feas)"]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for name, T in keys:
            ido = idx.get(("stlpy", name, T, "idstlpy", "-"))
            cells = [name, str(T), _cell(ido, timeout), _verif(ido)]
            for tool, m in cols:
                cells.append(_cell(idx.get(("stlpy", name, T, tool, m)), timeout))
            best = _best_open(idx, name, T)
            cells.append(_ratio(ido, best, timeout))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        out.append("### stlpy scenarios: ratio idstlpy end-to-end / peer end-to-end\n")
        out.append(
            "Below 1 means idstlpy is faster (0.1 = 10x faster). `<x` / `>x`: a bound, one side timed out.\n"
        )
        head = ["scenario", "T"] + [f"{t.split('+')[1]} {m[:4]}" for t, m in cols]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for name, T in keys:
            ido = idx.get(("stlpy", name, T, "idstlpy", "-"))
            cells = [name, str(T)]
            cells += [_ratio(ido, idx.get(("stlpy", name, T, t, m)), timeout) for t, m in cols]
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        out.append("### stlpy scenarios: build / solve split (seconds, median)\n")
        head = [
            "scenario",
            "T",
            "tool",
            "mode",
            "status",
            "build",
            "solve",
            "e2e",
            "MICP size (vars/cons/bin)",
            "detail",
        ]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for r in sorted(st, key=lambda r: (_order(r["scenario"]), r["T"], r["tool"], r["mode"])):
            if r["status"] == "not_run":
                continue
            size = f"{r.get('nvars')}/{r.get('ncons')}/{r.get('nbin')}" if r.get("nvars") else ""
            out.append(
                f"| {r['scenario']} | {r['T']} | {r['tool']} | {r['mode']} | {r['status']} | "
                f"{_t(r.get('build_s'))} | {_t(r.get('solve_s'))} | {_t(r.get('e2e_s'))} | {size} | "
                f"{str(r.get('detail', ''))[:80]} |"
            )
        out.append("")
    pr = [r for r in rows if r["suite"] == "prstl"]
    if pr:
        out.append("### PrSTL (noisy reach-avoid): idstlpy vs the chance-constrained MILP (HiGHS)\n")
        head = [
            "T",
            "tool",
            "status",
            "verified (monitor)",
            "build",
            "solve",
            "e2e",
            "margin",
            "idstlpy / MILP",
        ]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for T in sorted({r["T"] for r in pr}):
            ido = idx.get(("prstl", "NoisyReachAvoid", T, "idstlpy", "feasibility"))
            mil = idx.get(("prstl", "NoisyReachAvoid", T, "cc-milp+highs", "feasibility"))
            for r in (ido, mil):
                if r is None:
                    continue
                ratio = _ratio(ido, mil, timeout) if r is ido else ""
                margin = r.get("margin")
                out.append(
                    f"| {T} | {r['tool']} | {r['status']} | {_verif(r)} | {_t(r.get('build_s'))} | "
                    f"{_t(r.get('solve_s'))} | {_t(r.get('e2e_s'))} | "
                    f"{'' if margin in (None, '') else f'{float(margin):.3g}'} | {ratio} |"
                )
        out.append("")
    ld = [r for r in rows if r["suite"] == "light_dark"]
    if ld:
        out.append(
            "### Light-dark (paper listing: rrt_timeout=60, delta_near=2, delta_drain=0.5, "
            "goal_bias=0.25, 3..15 steps)\n"
        )
        head = [
            "variant",
            "seeds",
            "success",
            "verified",
            "median solve (s)",
            "max solve (s)",
            "median / 60 s",
            "median stretched / listing",
        ]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        med: dict[str, float] = {}
        by = defaultdict(list)
        for r in ld:
            by[r["scenario"]].append(r)
        for variant, rs in by.items():
            med[variant] = _median_list([float(r["e2e_s"]) for r in rs if r.get("status") == "solved"])
        for variant, rs in by.items():
            ok = [r for r in rs if r.get("status") == "solved"]
            ver = [r for r in ok if r.get("verified") in (True, "True")]
            times = [float(r["e2e_s"]) for r in ok]
            m = med[variant]
            base = med.get("light_dark[listing]")
            stretch = f"{m / base:.3g}" if "stretched" in variant and base else ""
            out.append(
                f"| {variant} | {len(rs)} | {len(ok)}/{len(rs)} | {len(ver)}/{len(ok)} | {_t(m)} | "
                f"{_t(max(times) if times else float('nan'))} | {m / 60:.3g} | {stretch} |"
            )
        out.append("")
    return "\n".join(out)


def _median_list(xs: list[float]) -> float:
    if not xs:
        return float("nan")
    xs = sorted(xs)
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def _verif(row: dict[str, Any] | None) -> str:
    if row is None or row.get("status") != "solved":
        return "-"
    v = row.get("verified")
    if v in (True, "True"):
        if "stlpy_robustness" in row:
            return f"yes (rho={float(row['stlpy_robustness']):.2g}, monitor ok)"
        return "yes"
    return "NO"


_ORDER = ["ReachAvoid", "EitherOr", "NarrowPassage", "RandomMultitarget", "DoorPuzzle", "SteppingStones"]


def _order(name: str) -> int:
    return _ORDER.index(name) if name in _ORDER else len(_ORDER)


def _best_open(idx: dict[tuple, dict[str, Any]], name: str, T: int) -> dict[str, Any] | None:
    """The faster of stlpy+HiGHS / stlpy+SCIP in feasibility mode (a timeout if both timed out)."""
    cands = [idx.get(("stlpy", name, T, f"stlpy+{p}", "feasibility")) for p in ("highs", "scip")]
    cands = [c for c in cands if c is not None]
    solved = [c for c in cands if c.get("status") == "solved"]
    if solved:
        return min(solved, key=lambda c: c["e2e_s"])
    timed = [c for c in cands if c.get("status") in ("timeout", "killed")]
    return timed[0] if timed else None


def plot_scaling(rows: Sequence[dict[str, Any]], path: Path, timeout: float) -> bool:
    """End-to-end time vs T per scenario (log scale); timeouts drawn at the limit as crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = [r for r in rows if r["suite"] == "stlpy" and r["status"] != "not_run"]
    pr = [r for r in rows if r["suite"] == "prstl" and r["status"] != "not_run"]
    names = sorted({r["scenario"] for r in st}, key=_order)
    panels = names + (["NoisyReachAvoid (PrSTL)"] if pr else [])
    if not panels:
        return False
    ncol = 3
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5 * ncol, 3.8 * nrow), squeeze=False)
    styles = {
        ("idstlpy", "-"): ("k", "-", "idstlpy"),
        ("idstlpy", "feasibility"): ("k", "-", "idstlpy"),
        ("stlpy+gurobi", "feasibility"): ("tab:red", "-", "stlpy+Gurobi feas"),
        ("stlpy+highs", "feasibility"): ("tab:blue", "-", "stlpy+HiGHS feas"),
        ("stlpy+scip", "feasibility"): ("tab:green", "-", "stlpy+SCIP feas"),
        ("stlpy+gurobi", "robustness"): ("tab:red", "--", "stlpy+Gurobi max-rho"),
        ("stlpy+highs", "robustness"): ("tab:blue", "--", "stlpy+HiGHS max-rho"),
        ("stlpy+scip", "robustness"): ("tab:green", "--", "stlpy+SCIP max-rho"),
        ("cc-milp+highs", "feasibility"): ("tab:purple", "-", "chance-constrained MILP (HiGHS)"),
    }
    for ax, panel in zip(axes.ravel(), panels, strict=False):
        data = pr if panel.startswith("NoisyReachAvoid") else [r for r in st if r["scenario"] == panel]
        groups = defaultdict(list)
        for r in data:
            groups[(r["tool"], r["mode"])].append(r)
        for key, rs in groups.items():
            color, ls, label = styles.get(key, ("gray", ":", f"{key[0]} {key[1]}"))
            rs = sorted(rs, key=lambda r: r["T"])
            ok = [(r["T"], float(r["e2e_s"])) for r in rs if r["status"] == "solved"]
            bad = [(r["T"], timeout) for r in rs if r["status"] in ("timeout", "killed")]
            if ok:
                ax.plot(*zip(*ok, strict=True), color=color, ls=ls, marker="o", ms=4, label=label)
            if bad:
                ax.plot(
                    *zip(*bad, strict=True),
                    color=color,
                    ls="none",
                    marker="x",
                    ms=9,
                    label=None if ok else f"{label} (timeout)",
                )
        ax.axhline(timeout, color="gray", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_title(panel)
        ax.set_xlabel("horizon T")
        ax.set_ylabel("end-to-end time (s)")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.ravel()[len(panels) :]:
        ax.axis("off")
    handles, labels = {}, {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
            labels[lab] = lab
    fig.legend(list(handles.values()), list(labels), loc="lower center", ncol=4, fontsize=8)
    fig.suptitle(f"Horizon scaling (x = timeout at {timeout:g} s)")
    fig.tight_layout(rect=(0, 0.07, 1, 0.96))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


RUNNER_SECTIONS = ("Run", "What is measured", "Results", "Horizon scaling", "Analysis")
"""The ``## `` sections of BENCHMARKS.md this runner writes; every other section is someone else's."""

KEPT_FILES = ("core_results.md", "robustness_results.md", "closed_loop_results.md")
"""Results measured by other scripts and kept beside the code (``benchmarks/``): a regeneration
re-appends a kept file's section when BENCHMARKS.md has lost it (neither its title nor a link)."""


def write_benchmarks_md(
    path: Path,
    tables: str,
    command: str,
    mach: dict[str, str],
    timeout: float,
    repeats: int,
    plot_rel: str | None,
    started: str,
    wall: float,
    analysis: str | None,
    load: str | None = None,
    suites: Sequence[str] | None = None,
) -> None:
    """Refresh this runner's sections of BENCHMARKS.md and keep everyone else's.

    The file is re-read right before it is written (other scripts and people edit their own
    sections of it) and replaced atomically. Only the ``## `` sections in :data:`RUNNER_SECTIONS`
    are rewritten; inside ``## Results`` only the ``### `` tables this run produced are (a run
    of one suite keeps the other suites' tables). Sections of the kept result files
    (:data:`KEPT_FILES`) are re-appended if a regeneration ever lost them.
    """
    generated = {
        "Run": "\n".join(
            [
                f"- command: `{command}`",
                f"- started: {started}; wall time {wall / 60:.1f} min",
                f"- machine: nproc = {mach['nproc']}, CPU: {mach['cpu']}",
                f"- {mach['python']} on {mach['platform']}",
                f"- packages: {mach['packages']}",
                f"- idstlpy revision: {mach['git']}",
                f"- time limit per run: {timeout:g} s (solver's own limit, plus a hard kill of the worker "
                f"process); repeats: {repeats} (median; a timeout is not repeated)",
            ]
            + ([f"- load average (1 min, 2 cores shared with other jobs): {load}"] if load else [])
            + (
                [
                    f"- suites run: {', '.join(suites)}; the Results tables of suites not run are kept from "
                    "their own earlier runs (each says so)"
                ]
                if suites
                else []
            )
        ),
        "What is measured": "\n".join(
            [
                "- **stlpy scenarios** (stlpy 0.3 `stlpy.benchmarks`, parameters and `x0` of stlpy's example "
                "scripts, `|u_i| <= 0.5` and the examples' state box for both tools). idstlpy gets the "
                "specification translated *automatically* (`benchmarks/stlpy_translate.py`: stlpy's "
                "expanded and/or trees are recognised as always / eventually / until, each predicate "
                "`a'y - b >= 0` becomes a chance constraint with eps = 0.01 on a noise-free system with zero "
                "initial covariance, so PrSTL reduces to STL; the state box becomes `G[0,T] box`). Every "
                "idstlpy plan is checked by stlpy's own `spec.robustness(y, 0) >= -1e-6` on a fresh "
                "specification, by a dynamics / bounds replay, and by `idstlpy.satisfies`.",
                "- **stlpy's MICP** (`GurobiMICPSolver` builds the gurobipy model after `spec.simplify()`, "
                "big-M = 1000): Gurobi only when the size-limited pip licence admits the model (<= 2000 "
                "variables and constraints), otherwise written to MPS and solved with HiGHS (highspy) and "
                "SCIP (pyscipopt). `feas` = `robustness_cost=False` (rho >= 0, no objective), `robu` = "
                "stlpy's default `robustness_cost=True` (maximise rho). The examples' optional quadratic "
                "running cost is left out (MIQP). Gurobi is driven with `model.optimize()` directly because "
                "`GurobiMICPSolver.Solve()` drops an incumbent found before a time limit. Peer solutions are "
                "verified the same way.",
                "- Build time = specification + encoding (+ MPS write/read for the open solvers); solve time "
                "= the solver call; end-to-end = both (process start-up and imports excluded for "
                "every tool).",
            ]
        ),
        "Results": tables.strip(),
    }
    if plot_rel:
        generated["Horizon scaling"] = f"![horizon scaling]({plot_rel})"
    if analysis:
        generated["Analysis"] = analysis.strip()
    old = Path(path).read_text() if Path(path).exists() else ""
    text = merge_benchmarks_md(old, generated)
    text = _keep_results(text, Path(__file__).resolve().parent)
    tmp = Path(path).with_name(f".{Path(path).name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


_HEADER = (
    "# Benchmarks\n\nGenerated by `python -m benchmarks` (see `benchmarks/`) for the sections it owns "
    "(Run, What is measured, Results, Horizon scaling, Analysis); the other sections are written by "
    "the scripts and people they name, and a regeneration keeps them.\n"
)


def _split(text: str, marker: str) -> tuple[str, list[tuple[str, str]]]:
    """``(preamble, [(title, body), ...])`` of the sections that start with ``marker`` (e.g. ``## ``).

    Lines inside fenced code blocks are never headings.
    """
    pre: list[str] = []
    sections: list[tuple[str, list[str]]] = []
    fenced = False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith(marker):
            sections.append((line[len(marker) :].strip(), []))
        elif sections:
            sections[-1][1].append(line)
        else:
            pre.append(line)
    return "\n".join(pre), [(t, "\n".join(b)) for t, b in sections]


def _join(pre: str, sections: Sequence[tuple[str, str]], marker: str) -> str:
    parts = [pre.rstrip("\n")] if pre.strip() else []
    for title, body in sections:
        parts.append(f"{marker}{title}\n\n{body.strip(chr(10))}".rstrip())
    return "\n\n".join(parts) + "\n"


def _owner(title: str, names: Sequence[str]) -> str | None:
    for name in names:
        if title == name or title.startswith(name + ":") or title.startswith(name + " ("):
            return name
    return None


def _merge_results(old: str, new: str) -> str:
    """Replace the ``### `` tables ``new`` has, keep the ones it has not (another suite's)."""
    old_pre, old_subs = _split(old, "### ")
    new_pre, new_subs = _split(new, "### ")
    fresh = {t: b for t, b in new_subs}
    out: list[tuple[str, str]] = []
    used: set[str] = set()
    for title, body in old_subs:
        if title in fresh:
            out.append((title, fresh[title]))
            used.add(title)
        else:
            out.append((title, body))
    # Tables this run made that the file did not have go after the last one it replaced.
    at = max((i for i, (t, _) in enumerate(out) if t in used), default=len(out) - 1) + 1
    out[at:at] = [(t, b) for t, b in new_subs if t not in used]
    return _join(new_pre if new_pre.strip() else old_pre, out, "### ").strip("\n")


def merge_benchmarks_md(old: str, generated: dict[str, str]) -> str:
    """``old`` with the runner's ``## `` sections replaced by ``generated`` (title -> body).

    Sections the runner does not own keep their text and their place; a runner section the file
    lacks is inserted after the runner section before it (or at the end).
    """
    pre, sections = _split(old, "## ")
    if not pre.strip() or "Generated by `python -m benchmarks`" in pre:
        pre = _HEADER  # the runner's own preamble (an older wording of it is replaced)
    out: list[tuple[str, str]] = []
    done: set[str] = set()
    for title, body in sections:
        name = _owner(title, RUNNER_SECTIONS)
        if name is None or name not in generated or name in done:
            if name is not None and name in done:
                continue  # a duplicate of a runner section: keep one
            out.append((title, body))
            continue
        new = generated[name]
        out.append((name, _merge_results(body, new) if name == "Results" else new))
        done.add(name)
    for name in RUNNER_SECTIONS:
        if name not in generated or name in done:
            continue
        before = [n for n in RUNNER_SECTIONS[: RUNNER_SECTIONS.index(name)] if n in done]
        at = len(out)
        if before:
            at = max(i for i, (t, _) in enumerate(out) if _owner(t, RUNNER_SECTIONS) == before[-1]) + 1
        out.insert(at, (name, generated[name]))
        done.add(name)
    return _join(pre, out, "## ")


def _keep_results(text: str, folder: Path) -> str:
    """Re-append what ``text`` lost of the kept result files (see :data:`KEPT_FILES`).

    A file that is one ``## `` section of BENCHMARKS.md (the core's) comes back as that section;
    a file with its own ``# `` title (a report of its own) comes back as a link under
    ``## Further results``, so its text lives in one place.
    """
    links: list[str] = []
    for name in KEPT_FILES:
        f = folder / name
        if not f.exists():
            continue
        body = f.read_text().strip()
        first = body.splitlines()[0] if body else ""
        title = first.lstrip("#").strip()
        if not title or title in text or f"benchmarks/{name}" in text:
            continue
        if first.startswith("## "):
            text = text.rstrip("\n") + "\n\n" + body + "\n"
        else:
            links.append(f"- [{title}](benchmarks/{name})")
    if links:
        pre, sections = _split(text, "## ")
        further = dict(sections).get("Further results", "")
        lines = [ln for ln in further.strip().splitlines() if ln.strip()] + links
        sections = [(t, b) for t, b in sections if t != "Further results"]
        sections.append(("Further results", "\n".join(lines)))
        text = _join(pre, sections, "## ")
    return text


def command_line() -> str:
    return "python -m benchmarks " + " ".join(sys.argv[1:])
