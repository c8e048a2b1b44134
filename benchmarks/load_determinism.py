"""Issue 32 item 7: a default solve gives the same plan on an idle and on a loaded machine.

Every kind of :mod:`benchmarks.perception_problems` (``--size``, default ``small``) is solved
with the default options and ``seed`` twice: once as the machine is, once with one busy-loop
process per core started beside it (stopped by pid afterwards). Each solve runs in a fresh child
process; the plan (modes, inputs, means: SHA-256 of their bytes), the status, the reason, the
work counters and the caps hit are compared. The wall times are recorded, not compared.

Usage::

    python -m benchmarks.load_determinism [--size small] [--seed 0] [--kinds a,b] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COUNTS = ("candidates", "refuted", "abandoned", "lp_calls", "sampler_iterations", "nodes", "predictions")


def one(kind: str, size: str, seed: int) -> dict[str, object]:
    """Solve one kind with the default options (in this process) and fingerprint the answer."""
    import warnings

    import numpy as np

    from benchmarks import perception_problems as pp

    problem, _ = pp.build(kind, size)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = problem.solve_result(seed=seed)
    wall = time.perf_counter() - t0
    digest = "-"
    for traj in (result.plan, result.closest):
        if traj is not None:
            h = hashlib.sha256()
            for arr in (traj.get_action(), traj.get_control(), traj.get_mean()):
                h.update(np.ascontiguousarray(arr).tobytes())
            digest = h.hexdigest()[:16]
            break
    return {
        "kind": kind,
        "status": result.status,
        "reason": result.reason,
        "plan": digest,
        "steps": None if result.plan is None else result.plan.num_of_steps,
        "counts": {c: getattr(result.stats, c) for c in COUNTS},
        "caps": list(result.stats.caps_hit),
        "wall": wall,
    }


def run(kind: str, size: str, seed: int) -> dict[str, object]:
    """:func:`one` in a fresh child process."""
    cmd = [sys.executable, "-m", "benchmarks.load_determinism", "--one", kind, size, str(seed)]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode or not lines:
        return {"kind": kind, "status": "error", "reason": out.stderr.strip()[-300:], "plan": "-",
                "steps": None, "counts": {}, "caps": [], "wall": float("nan")}  # fmt: skip
    return json.loads(lines[-1])


@contextmanager
def busy(processes: int) -> Iterator[None]:
    """``processes`` busy-loop processes beside the block (stopped by their pid)."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(processes)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def main(argv: Sequence[str] | None = None) -> int:
    from benchmarks import perception_problems as pp

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--size", default="small", choices=pp.SIZES)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default=",".join(pp.KINDS))
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if args.one:
        kind, size, seed = args.one
        print(json.dumps(one(kind, size, int(seed))), flush=True)
        return 0
    kinds = args.kinds.split(",")
    load0 = os.getloadavg()[0]
    idle = [run(k, args.size, args.seed) for k in kinds]
    with busy(os.cpu_count() or 2):
        time.sleep(1.0)  # the hogs at full speed before the first solve
        loaded = [run(k, args.size, args.seed) for k in kinds]
    same = 0
    rows = []
    for a, b in zip(idle, loaded, strict=True):
        keys = ("status", "reason", "plan", "counts", "caps")
        equal = all(a[k] == b[k] for k in keys)
        same += equal
        diff = ", ".join(k for k in keys if a[k] != b[k]) or "-"
        rows.append(
            f"| {a['kind']} | {a['status']} | {a['steps']} | {a['plan']} | {b['plan']} | "
            f"{float(a['wall']):.2f} | {float(b['wall']):.2f} | {','.join(a['caps']) or '-'} | "
            f"{'yes' if equal else '**no**'} | {diff} |"
        )
        print(rows[-1], flush=True)
    command = "python -m benchmarks.load_determinism " + " ".join(argv if argv is not None else sys.argv[1:])
    text = "\n".join(
        [
            "## Default solves idle and loaded (issue 32, item 7)",
            "",
            f"`{command.strip()}`: {len(kinds)} kinds at size {args.size}, seed {args.seed}, default "
            f"options; load average {load0:.1f} at the start of the first pass (other work on the "
            f"machine), the second pass with {os.cpu_count()} busy-loop processes beside it.",
            "",
            f"**{same} of {len(kinds)} identical** (plan bytes, status, reason, work counters, caps).",
            "",
            "| kind | status | steps | plan (first pass) | plan (loaded) | s first | s loaded | caps | same "
            "| differs in |",
            "|" + "---|" * 10,
            *rows,
            "",
        ]
    )
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    return 0 if same == len(kinds) else 1


if __name__ == "__main__":
    raise SystemExit(main())
