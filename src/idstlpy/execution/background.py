"""One job at a time beside a control loop: a worker process (or thread) polled without waiting.

:class:`~idstlpy.ReplanningExecutor` with ``background=True`` hands its checks and re-solves to a
:class:`BackgroundWorker` so that ``step()`` never waits for a solve: it submits a job, keeps
stepping, and polls for the answer.

Why a process by default: a solve is mostly Python; in a thread it holds the interpreter lock for
up to ``sys.getswitchinterval()`` (5 ms) at a time, and the control loop's ``step`` waits for it.
The worker process is forked once, when the worker is made, so the job's function and what it
closes over (the problem, whose noise functions may be lambdas that cannot be pickled) are
inherited, not sent; only the job's argument and its result cross the pipe. Where ``fork`` is not
available (Windows, or ``kind="thread"``), a thread runs the jobs, and a step may wait for the
lock.

Cancelling (:meth:`BackgroundWorker.cancel`) ends the process running a job at once and forks a
fresh one; a thread cannot be interrupted, so its job runs to its end and its answer is dropped.

Fork copies only the thread that forks: a lock held by another thread at that moment stays held
in the worker forever (measured: a worker forked while a thread of this module was solving
never answered). Make the executor before other threads start computing (a ROS 2 node: before
it spins); :meth:`BackgroundWorker.close` of a thread worker waits for its job to end so that a
later fork is safe.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import threading
import weakref
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, Generic, Literal, TypeVar

from ..errors import InvalidArgumentError

__all__ = ["BackgroundKind", "BackgroundWorker", "JobError"]

logger = logging.getLogger(__name__)

A = TypeVar("A")
R = TypeVar("R")

BackgroundKind = Literal["process", "thread"]
"""Where the jobs run."""


class JobError:
    """What a job that raised returns in its place: the exception, as text.

    Parameters
    ----------
    text : str
        ``"TypeName: message"``.
    """

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return f"JobError({self.text!r})"


def _serve(conn: Connection, fn: Callable[[Any], Any]) -> None:
    """The worker process: answer ``(job_id, fn(arg))`` to every ``(job_id, arg)`` until None."""
    # Under SCHED_BATCH (Linux) the worker woken by a job does not preempt the control loop at
    # the very write that wakes it (measured: 7-19 ms submits on a loaded machine without it).
    # Its niceness is left alone: at nice 10, or under SCHED_IDLE, a re-solve on a machine
    # shared with busy processes got a few percent of a core and took minutes.
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        job_id, arg = job
        try:
            result: Any = fn(arg)
        except Exception as exc:  # a job's failure is its answer: the loop decides what to do
            result = JobError(f"{type(exc).__name__}: {exc}")
        try:
            conn.send((job_id, result))
        except (BrokenPipeError, OSError):
            return


def _stop(process: Any, conn: Connection | None) -> None:
    """End a worker process (a finaliser: it must not refer to the worker object)."""
    try:
        if conn is not None:
            conn.close()
    finally:
        if process is not None and process.is_alive():
            process.terminate()
            process.join(1.0)


class BackgroundWorker(Generic[A, R]):
    """Runs ``fn(arg)`` for one job at a time beside the caller, who polls for the answer.

    Parameters
    ----------
    fn : callable
        The job: ``arg -> result``; the argument and the result must pickle (a process
        worker sends them through a pipe); ``fn`` itself need not.
    kind : {"process", "thread"}
        ``"process"`` (default): a forked process (``"thread"`` where fork is not available).

    Raises
    ------
    InvalidArgumentError
        For another ``kind``.
    """

    def __init__(self, fn: Callable[[A], R], kind: BackgroundKind = "process") -> None:
        if kind not in ("process", "thread"):
            raise InvalidArgumentError(f"background must be 'process' or 'thread', got {kind!r}")
        if kind == "process" and "fork" not in multiprocessing.get_all_start_methods():
            logger.info("background: fork is not available here; the jobs run in a thread")
            kind = "thread"
        self.kind: BackgroundKind = kind
        self._fn = fn
        self._next_id = 0
        self._running: int | None = None  # the job in flight
        self._done: tuple[int, R | JobError] | None = None  # a thread's answer, once in
        self._lock = threading.Lock()
        self._event = threading.Event()  # a thread's answer is in
        self._thread: threading.Thread | None = None
        self._conn: Connection | None = None
        self._process: Any = None
        self._finalizer: weakref.finalize[Any, Any] | None = None
        if kind == "process":
            self._start()

    def _start(self) -> None:
        """Fork the worker process (done once, outside the control loop's steps)."""
        ctx = multiprocessing.get_context("fork")
        parent, child = ctx.Pipe()
        process = ctx.Process(target=_serve, args=(child, self._fn), daemon=True, name="idstlpy-replan")
        process.start()
        child.close()
        self._conn, self._process = parent, process
        self._finalizer = weakref.finalize(self, _stop, process, parent)

    @property
    def busy(self) -> bool:
        """True while a job is in flight (submitted, answer not yet taken by :meth:`poll`)."""
        return self._running is not None

    def submit(self, arg: A) -> int:
        """Start a job (none may be in flight); returns its id. Costs the pickling of ``arg``.

        Raises
        ------
        InvalidArgumentError
            When a job is in flight or the worker is closed.
        """
        if self._running is not None:
            raise InvalidArgumentError("a background job is in flight: poll for it or cancel it first")
        job_id = self._next_id
        self._next_id += 1
        self._running = job_id
        if self.kind == "process":
            if self._conn is None:
                raise InvalidArgumentError("the background worker is closed")
            self._conn.send((job_id, arg))
        else:
            self._event.clear()
            self._thread = threading.Thread(target=self._run_thread, args=(job_id, arg), daemon=True)
            self._thread.start()
        return job_id

    def _run_thread(self, job_id: int, arg: A) -> None:
        try:
            result: R | JobError = self._fn(arg)
        except Exception as exc:
            result = JobError(f"{type(exc).__name__}: {exc}")
        with self._lock:
            if self._running == job_id:
                self._done = (job_id, result)
                self._event.set()

    def poll(self) -> tuple[int, R | JobError] | None:
        """The answer of the job in flight when it is in (taken once), else None; never waits."""
        if self._running is None:
            return None
        if self.kind == "thread":
            with self._lock:
                done, self._done = self._done, None
        else:
            done = self._conn.recv() if self._conn is not None and self._conn.poll() else None
        if done is not None:
            self._running = None
        return done

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the job in flight has answered (for a simulated loop and tests); True
        when an answer is in (or nothing is in flight).

        Parameters
        ----------
        timeout : float, optional
            Seconds at most (None: no limit).
        """
        if self._running is None:
            return True
        if self.kind == "process":
            return self._conn is not None and self._conn.poll(timeout)
        return self._event.wait(timeout)

    def cancel(self) -> None:
        """Drop the job in flight: a process is ended at once (and a fresh one forked), a thread
        runs to its end and its answer is discarded."""
        if self._running is None:
            return
        self._running = None
        if self.kind == "thread":
            with self._lock:
                self._done = None
            return
        self.close()
        self._start()

    def close(self) -> None:
        """End the worker (the job in flight is dropped; a thread's job is waited for, module
        notes). Idempotent."""
        self._running = None
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._finalizer is not None:
            self._finalizer()  # ends the process and closes the pipe, once
            self._finalizer = None
        self._conn, self._process = None, None
