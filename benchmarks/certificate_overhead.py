"""What certifying ``infeasible`` costs (issue 32, item 6): the certificate's share of solve time.

``python -m benchmarks.certificate_overhead [--seeds 25] [--families reach,confidence,modes,contradiction]``

Solves the infeasible-by-construction families of the soundness tests
(``tests/oracles/generators.py``, the options of ``tests/test_soundness.py``) and the problems of
``tests/test_certificates.py``; for each ``infeasible`` it reports whether the certificate
verifies (re-checked from its JSON with :func:`idstlpy.synthesis.certificates.check_certificate`)
and ``stats.time_certificate / stats.time_total`` (building and checking the certificate, and,
for an eager MILP proof, the lazy loop's re-derivation). Timings vary with the machine's load;
the counts do not.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cases(seeds: int, families: list[str]) -> Iterator[tuple[str, Callable[[], object]]]:
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    from test_certificates import PROBLEMS
    from test_soundness import _solve
    from tests.oracles.generators import infeasible_instance

    for name, make in PROBLEMS.items():
        yield f"certificates/{name}", lambda make=make: make().solve_result(rrt_timeout=30, seed=0)
    for family in families:
        for seed in range(seeds):
            inst = infeasible_instance(seed * 7919 + 13, family=family)
            yield f"{family}/{seed}", lambda inst=inst: _solve(inst)


def main(argv: list[str] | None = None) -> int:
    """Run the measurement and print one line per case and a summary."""
    from idstlpy.synthesis.certificates import check_certificate

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=25)
    parser.add_argument("--families", default="reach,confidence,modes,contradiction")
    args = parser.parse_args(argv)
    rows = []
    for name, solve in _cases(args.seeds, args.families.split(",")):
        result = solve()
        if getattr(result, "status", None) != "infeasible":
            continue
        cert = result.certificate  # type: ignore[attr-defined]
        check = check_certificate(json.loads(json.dumps(cert)))
        stats = result.stats  # type: ignore[attr-defined]
        share = stats.time_certificate / stats.time_total if stats.time_total > 0 else 0.0
        rows.append((name, check.ok and check.certified, stats.time_total, stats.time_certificate, share))
        print(
            f"{name:32s} {'certified' if rows[-1][1] else 'NOT certified':14s} "
            f"{stats.time_total:7.3f} s  certificate {stats.time_certificate:6.3f} s ({100 * share:4.1f}%)"
            + ("" if rows[-1][1] else f"  {check.summary()[:120]}")
        )
    if not rows:
        print("no infeasible result")
        return 0
    total = sum(r[2] for r in rows)
    spent = sum(r[3] for r in rows)
    shares = sorted(r[4] for r in rows)
    print(
        f"\n{len(rows)} infeasible, {sum(r[1] for r in rows)} certified; certificate time "
        f"{spent:.2f} s of {total:.2f} s solve time ({100 * spent / total:.1f}%); per result: "
        f"median {100 * statistics.median(shares):.1f}%, 90th percentile "
        f"{100 * shares[int(0.9 * (len(shares) - 1))]:.1f}%, max {100 * shares[-1]:.1f}%"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
