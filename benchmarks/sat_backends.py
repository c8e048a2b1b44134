"""Which SAT back-end serves the BMC encoding fastest? (python-sat's CaDiCaL / Glucose / MiniSat vs z3)

Run: ``python -m benchmarks.sat_backends`` (needs ``z3-solver``, in the ``bench`` extra).

The workload is what the synthesis loop asks of the proposer on the light-dark problem: the
initial satisfiability check, the binary search for the shortest depth (assumption on the trace
length), and a series of prefix-consistency queries (assumptions fixing realised labels), all on
one incremental solver. The CNF is the same for every back-end.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from idstlpy.scenarios import light_dark
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.bmc import BMCEncoder


def _queries(enc: BMCEncoder, rng: np.random.Generator, count: int) -> list[list[int]]:
    H = enc.H
    out: list[list[int]] = []
    lo, hi = 0, H
    while lo < hi:  # the depth binary search
        mid = (lo + hi) // 2
        out.append([-enc.alive[mid + 1]])
        hi = mid if mid > H // 5 else hi
        lo = mid + 1 if mid <= H // 5 else lo
    for _ in range(count):  # realised prefixes: free space holds, target does not yet
        k = int(rng.integers(1, H // 2))
        out.append([-int(v) for v in enc.p[1, :k]] + [int(v) for v in enc.p[0, : rng.integers(0, k)]])
    return out


def run_pysat(name: str, clauses, queries) -> tuple[float, float, list[bool]]:
    from pysat.solvers import Solver

    t0 = time.perf_counter()
    s = Solver(name=name, bootstrap_with=clauses)
    t1 = time.perf_counter()
    answers = [bool(s.solve(assumptions=q)) for q in queries]
    t2 = time.perf_counter()
    s.delete()
    return t1 - t0, t2 - t1, answers


def run_z3(clauses, nvars: int, queries) -> tuple[float, float, list[bool]]:
    import z3

    t0 = time.perf_counter()
    v = [None] + [z3.Bool(f"v{i}") for i in range(1, nvars + 1)]
    s = z3.Solver()
    for c in clauses:
        s.add(z3.Or([v[lit] if lit > 0 else z3.Not(v[-lit]) for lit in c]))
    t1 = time.perf_counter()
    answers = []
    for q in queries:
        lits = [v[lit] if lit > 0 else z3.Not(v[-lit]) for lit in q]
        answers.append(s.check(*lits) == z3.sat)
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, answers


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--deadline", type=int, default=960)
    ap.add_argument("--hold", type=int, default=160)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    problem = light_dark(args.deadline, args.hold)
    abstraction = Abstraction(problem.stl_formula, 2)
    t0 = time.perf_counter()
    enc = BMCEncoder(problem.stl_formula, abstraction.atoms, 1)
    t_encode = time.perf_counter() - t0
    queries = _queries(enc, np.random.default_rng(0), args.queries)
    clauses, nvars = enc.clauses, enc.num_vars
    enc.close()
    print(
        f"encoding: {nvars} vars, {len(clauses)} clauses, built in {t_encode:.3f} s; "
        f"{len(queries)} incremental queries\n"
    )
    backends = {
        name: (lambda n=name: run_pysat(n, clauses, queries))
        for name in ("cadical195", "glucose4", "minisat22")
    }
    backends["z3"] = lambda: run_z3(clauses, nvars, queries)
    rows = []
    reference = None
    for name, fn in backends.items():
        loads, solves = [], []
        for _ in range(args.repeats):
            load, solve, answers = fn()
            loads.append(load)
            solves.append(solve)
        if reference is None:
            reference = answers
        agree = answers == reference
        rows.append((name, statistics.median(loads), statistics.median(solves), agree))
    best = min(r[1] + r[2] for r in rows)
    print("| back-end | load (s) | queries (s) | total / best | same answers |")
    print("|---|---|---|---|---|")
    for name, load, solve, agree in rows:
        print(f"| {name} | {load:.4f} | {solve:.4f} | {(load + solve) / best:.1f}x | {agree} |")


if __name__ == "__main__":
    main()
