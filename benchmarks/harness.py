"""Run benchmark jobs in a separate process with a hard wall-clock limit.

A :class:`Worker` owns one ``spawn`` child process that imports everything once (so import time
is never measured) and then executes jobs sent over a pipe. When a job overruns its hard limit
the child is killed (by its own pid) and a fresh one is started for the next job; the job is
reported with status ``killed``.
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing as mp
import os
import time
import traceback
from typing import Any

__all__ = ["Worker"]

logger = logging.getLogger(__name__)

_WARMUP = (
    "idstlpy",
    "idstlpy.scenarios",
    "stlpy.solvers",
    "stlpy.benchmarks",
    "gurobipy",
    "highspy",
    "pyscipopt",
    "scipy.optimize",
    "benchmarks.peers",
    "benchmarks.stlpy_translate",
    "benchmarks.prstl_milp",
)


def _silence_stdout() -> None:
    """Send the child's fd 1 to /dev/null: solver banners and stlpy's drake warning are noise."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)


def _loop(conn: Any) -> None:
    _silence_stdout()
    for name in _WARMUP:
        try:
            importlib.import_module(name)
        except Exception:  # a missing peer is reported by the job that needs it
            pass
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            return
        target, kwargs = msg
        mod_name, fn_name = target.rsplit(":", 1)
        try:
            fn = getattr(importlib.import_module(mod_name), fn_name)
            out = fn(**kwargs)
        except Exception as exc:
            out = {
                "status": "error",
                "detail": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=4),
            }
        conn.send(out)


class Worker:
    """One long-lived child process executing ``module:function`` jobs with a hard time limit."""

    def __init__(self) -> None:
        self._ctx = mp.get_context("spawn")
        self._start()

    def _start(self) -> None:
        self._conn, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_loop, args=(child,), daemon=True)
        self._proc.start()
        child.close()

    def run(self, target: str, kwargs: dict[str, Any], hard_limit: float) -> dict[str, Any]:
        """Run ``target(**kwargs)`` in the child; kill it after ``hard_limit`` seconds."""
        t0 = time.perf_counter()
        self._conn.send((target, kwargs))
        if self._conn.poll(hard_limit):
            try:
                return self._conn.recv()
            except EOFError:
                pass
            status, detail = "error", "worker process died"
        else:
            status, detail = "killed", f"hard limit of {hard_limit:.0f} s reached; worker killed"
        elapsed = time.perf_counter() - t0
        logger.warning("%s: %s", target, detail)
        self._kill()
        self._start()
        return {"status": status, "detail": detail, "e2e_s": elapsed}

    def _kill(self) -> None:
        if self._proc.is_alive():
            self._proc.kill()  # our own child, by its process object (pid)
        self._proc.join(5)
        self._conn.close()

    def close(self) -> None:
        """Stop the child."""
        try:
            self._conn.send(None)
        except (BrokenPipeError, OSError):
            pass
        self._proc.join(5)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5)

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
