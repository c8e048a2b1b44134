"""Where jobs run: in this process, in a process pool, or on a Dask cluster.

Every executor is a :class:`concurrent.futures.Executor`:

- ``"inprocess"``: :class:`InProcessExecutor` (runs each call at once in the calling thread);
- ``"processes"``: a :class:`~concurrent.futures.ProcessPoolExecutor` with the ``spawn``
  start method whose workers end themselves when the process that started them dies;
- ``"dask"``: :class:`DaskExecutor`, the executor of a ``distributed`` client
  (``Client.get_executor()``) on a scheduler address or on a ``LocalCluster``
  (``pip install 'idstlpy[dask]'``; imported only when used).

Process executors import the calling script in every worker (``spawn``): a script that creates
one must keep its top-level code under ``if __name__ == "__main__":`` (see ``docs/cli.md``).
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib.util
import multiprocessing
import os
import threading
import time
import urllib.parse
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from ..errors import InvalidArgumentError

__all__ = [
    "EXECUTORS",
    "PARENT_POLL_SECONDS",
    "InProcessExecutor",
    "DaskExecutor",
    "make_executor",
    "executor_width",
    "watch_parent",
]

EXECUTORS = ("inprocess", "processes", "dask")

PARENT_POLL_SECONDS = 1.0
"""How often a pool worker checks that the process that started it is still alive."""


class InProcessExecutor(cf.Executor):
    """Runs each submitted call at once, in the calling thread (no pickling, easy debugging)."""

    max_workers = 1

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        """Call ``fn(*args, **kwargs)`` now; its result or exception is in the returned future.

        Parameters
        ----------
        fn : callable
        *args, **kwargs
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Already done.
        """
        future: cf.Future = cf.Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            future.set_exception(exc)
        return future


def _watch(parent: int, interval: float) -> None:
    while True:
        time.sleep(interval)
        if os.getppid() != parent:
            os._exit(1)  # the parent died: nobody will collect this worker's results


def watch_parent(parent: int, interval: float = PARENT_POLL_SECONDS) -> None:
    """Process-pool initializer: end this worker when process ``parent`` is no longer its parent.

    A daemon thread polls :func:`os.getppid` every ``interval`` seconds; when the pool's owner
    dies (even by ``SIGKILL``, which runs no clean-up), the worker is re-parented and exits
    within about ``interval`` seconds instead of running its job to the end.

    Parameters
    ----------
    parent : int
        Process id of the process that creates the pool.
    interval : float
        Seconds between two checks.
    """
    if os.getppid() != parent:  # already orphaned before the first job
        os._exit(1)
    threading.Thread(target=_watch, args=(parent, interval), name="idstlpy-watch-parent", daemon=True).start()


LOOPBACK = "127.0.0.1"
"""Where a local Dask cluster listens unless told otherwise (:class:`DaskExecutor`'s ``host``)."""


class DaskExecutor(cf.Executor):
    """The ``concurrent.futures`` executor of a Dask ``distributed`` client (``Client.get_executor()``).

    This class only owns the client (and the local cluster it may start) so that
    :meth:`shutdown` closes them; submitting is ``distributed``'s own ``ClientExecutor``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``); without it a ``LocalCluster`` is
        started (and closed by :meth:`shutdown`).
    workers : int, optional
        Workers of the local cluster (default: the number of CPUs).
    processes : bool
        Local cluster with worker processes (default) or threads in this process.
    host : str
        The interface every port of a local cluster listens on: the scheduler, the workers, the
        nannies and the dashboard. The default, the loopback interface ``"127.0.0.1"``, lets no
        other machine reach the cluster (its dashboard shows the tasks, logs and profiles).
        Exposing it is explicit: ``host="0.0.0.0"`` (every interface) or one interface's address.

    Notes
    -----
    Workers of a remote cluster need ``idstlpy`` installed; jobs carry the problem text, so no
    shared filesystem is needed. :attr:`dashboard_link` is the address of the Dask dashboard
    (a local cluster's dashboard listens on a free port of ``host``).
    """

    def __init__(
        self,
        scheduler: str | None = None,
        workers: int | None = None,
        processes: bool = True,
        host: str = LOOPBACK,
    ) -> None:
        if not isinstance(host, str) or not host.strip():
            raise InvalidArgumentError(
                f"host must be an interface address such as {LOOPBACK!r}, got {host!r}"
            )
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise InvalidArgumentError(
                "the dask executor needs dask and distributed: pip install 'idstlpy[dask]'"
            ) from exc
        self._cluster: Any = None
        self._host = host
        if scheduler:
            self._client = Client(scheduler)
        else:
            # Every HTTP server (the scheduler's dashboard, each worker's status / metrics page)
            # on a free port of ``host``: without an address a worker's binds every interface.
            http = f"[{host}]:0" if ":" in host else f"{host}:0"
            self._cluster = LocalCluster(
                n_workers=workers or os.cpu_count() or 1,
                threads_per_worker=1,
                processes=processes,
                # Threads talk in-process (inproc://, no port); processes over TCP on ``host``.
                **({"host": host} if processes else {}),
                dashboard_address=http,
                worker_dashboard_address=http,
            )
            self._client = Client(self._cluster)
        self._executor = self._client.get_executor(pure=False)

    @property
    def client(self) -> Any:
        """The ``distributed.Client``."""
        return self._client

    @property
    def dashboard_link(self) -> str | None:
        """Address of the Dask dashboard (None when the scheduler runs none)."""
        try:
            link = self._client.dashboard_link
        except Exception:  # noqa: BLE001 - no dashboard service
            return None
        if not link:
            return None
        if self._cluster is not None and self._host not in ("0.0.0.0", "::"):
            # A threads cluster names the machine's address, where nothing listens: the host it is on.
            parts = urllib.parse.urlsplit(str(link))
            if parts.port is not None:
                where = f"[{self._host}]" if ":" in self._host else self._host
                return urllib.parse.urlunsplit(parts._replace(netloc=f"{where}:{parts.port}"))
        return str(link)

    @property
    def dashboard_needs_bokeh(self) -> bool:
        """True when a local cluster's dashboard cannot draw anything (``bokeh`` is not installed)."""
        return self._cluster is not None and importlib.util.find_spec("bokeh") is None

    @property
    def max_workers(self) -> int:
        """Threads across the cluster's workers."""
        try:
            return max(1, sum(self._client.nthreads().values()))
        except Exception:  # noqa: BLE001 - scheduler unreachable
            return 1

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        """Submit ``fn(*args, **kwargs)`` to the cluster (``ClientExecutor.submit``).

        Parameters
        ----------
        fn : callable
        *args, **kwargs
            Its arguments (pickled to the workers).

        Returns
        -------
        concurrent.futures.Future
        """
        return self._executor.submit(fn, *args, **kwargs)

    def map(
        self,
        fn: Callable[..., Any],
        *iterables: Iterable[Any],
        timeout: float | None = None,
        chunksize: int = 1,
    ) -> Iterator[Any]:
        """``ClientExecutor.map``: ``fn`` over the iterables, on the cluster.

        Parameters
        ----------
        fn : callable
        *iterables
            One per argument of ``fn``.
        timeout : float, optional
            Seconds to wait for all results.
        chunksize : int
            Ignored.

        Returns
        -------
        iterator
        """
        return self._executor.map(fn, *iterables, timeout=timeout)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Close the executor, the client and the local cluster (if this object started one).

        Parameters
        ----------
        wait : bool
            Wait for pending calls first.
        cancel_futures : bool
            Cancel pending calls instead of waiting for them.
        """
        try:
            self._executor.shutdown(wait=wait and not cancel_futures)
        finally:
            self._client.close()
            if self._cluster is not None:
                self._cluster.close()


def make_executor(
    kind: str = "inprocess", workers: int | None = None, scheduler: str | None = None
) -> cf.Executor:
    """An executor by name: ``"inprocess"``, ``"processes"`` or ``"dask"``.

    Parameters
    ----------
    kind : {"inprocess", "processes", "dask"}
        Where jobs run.
    workers : int, optional
        Worker processes (``processes``) or local-cluster workers (``dask``); default: CPUs.
    scheduler : str, optional
        Dask scheduler address (``dask`` only; default: a local cluster). Giving one with
        another ``kind`` is an error.

    Returns
    -------
    concurrent.futures.Executor
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InvalidArgumentError(f"workers must be a positive int, got {workers!r}")
    if scheduler and kind != "dask":
        raise InvalidArgumentError(f"a scheduler address needs the dask executor, got executor {kind!r}")
    if kind == "inprocess":
        return InProcessExecutor()
    if kind == "processes":
        # spawn: workers start clean (no forked threads or locks), the same on every platform
        return cf.ProcessPoolExecutor(
            max_workers=workers or os.cpu_count() or 1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=watch_parent,
            initargs=(os.getpid(),),
        )
    if kind == "dask":
        return DaskExecutor(scheduler=scheduler, workers=workers)
    raise InvalidArgumentError(f"executor must be one of {EXECUTORS}, got {kind!r}")


def executor_width(executor: cf.Executor) -> int:
    """How many calls ``executor`` runs at once (its workers; the CPU count when unknown).

    Parameters
    ----------
    executor : concurrent.futures.Executor

    Returns
    -------
    int
    """
    for attr in ("max_workers", "_max_workers"):
        value = getattr(executor, attr, None)
        if isinstance(value, int) and value > 0:
            return value
    return os.cpu_count() or 1
