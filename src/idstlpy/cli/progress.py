"""What the command line shows on stderr while it works (the library itself never prints).

- :class:`Ticker`: one stage at a time (``solving light_dark.toml``) with its elapsed time,
  updated every second by a thread, the solver's counters (candidates, refuted, abandoned, the
  current plan length, the sampler's iterations on the current candidate: the
  ``idstlpy.progress`` records, :mod:`idstlpy._progress`) and the latest INFO message of the
  ``idstlpy`` loggers (``candidate 3 abandoned: ...``) caught by a logging handler. On a terminal the line is
  rewritten in place; otherwise a line is printed when a stage starts, every
  :attr:`Ticker.plain_every` seconds while it lasts, and when it ends.
- :class:`ProgressBar`: ``[#####.....] 3/8 jobs`` for batches, called by
  :func:`~idstlpy.batch.run_jobs` after each job.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Mapping
from typing import Any, TextIO

__all__ = ["Ticker", "ProgressBar"]


class _LastMessage(logging.Handler):
    """Keeps the latest record's message (for the ticker's line); prints nothing."""

    def __init__(self) -> None:
        super().__init__(level=logging.INFO)
        self.message = ""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.message = " ".join(record.getMessage().split())
        except Exception:  # noqa: BLE001 - a bad log call must not stop the solve
            self.message = ""


class _Counters(logging.Handler):
    """Keeps the latest value of each counter the ``idstlpy.progress`` records carry."""

    def __init__(self) -> None:
        super().__init__(level=logging.DEBUG)
        self.counters: dict[str, int] = {}

    def emit(self, record: logging.LogRecord) -> None:
        got = getattr(record, "progress", None)
        if isinstance(got, Mapping):
            self.counters.update(got)

    def text(self) -> str:
        """``"12 candidates (9 refuted, 3 abandoned), length 31, sampler 2048 it"`` (or "")."""
        c = self.counters
        if "candidates" not in c:
            return ""
        out = (
            f"{c['candidates']} candidates ({c.get('refuted', 0)} refuted, {c.get('abandoned', 0)} abandoned)"
        )
        if c.get("below_target"):
            out += f", {c['below_target']} below target"
        out += f", length {c.get('length', 0)}"
        if c.get("sampler_iterations"):
            out += f", sampler {c['sampler_iterations']} it"
        return out


class Ticker:
    """A stage line with its elapsed time, refreshed every second by a daemon thread.

    Parameters
    ----------
    stream : file
        Where to write (stderr).
    enabled : bool
        False writes nothing at all.
    listen : bool
        Show the latest INFO message of the ``idstlpy`` loggers on the line (sets their level
        to INFO while a stage runs, without printing them anywhere else).
    """

    plain_every = 10.0
    """Seconds between two lines when the stream is not a terminal."""

    def __init__(self, stream: TextIO, enabled: bool = True, listen: bool = True) -> None:
        self.stream = stream
        self.enabled = enabled
        self.tty = enabled and bool(getattr(stream, "isatty", lambda: False)())
        self.listen = listen
        self._text = ""
        self._t0 = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._handler: _LastMessage | None = None
        self._counters: _Counters | None = None
        self._saved_level = logging.NOTSET
        self._saved_progress = (logging.NOTSET, True)

    # -- public --------------------------------------------------------------------------------
    def start(self, text: str) -> None:
        """Begin a stage (ends the current one).

        Parameters
        ----------
        text : str
            What is being done, e.g. ``"solving light_dark.toml (seed 0)"``.
        """
        self.stop()
        if not self.enabled:
            return
        self._text = text
        self._t0 = time.perf_counter()
        if self.listen:
            self._attach()
        if not self.tty:
            self._write(f"{text} ...\n")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="idstlpy-ticker", daemon=True)
        self._thread.start()

    def update(self, text: str) -> None:
        """Change the text of the current stage.

        Parameters
        ----------
        text : str
        """
        self._text = text

    def stop(self, summary: str | None = None) -> float:
        """End the current stage; returns its elapsed seconds (0 without a stage).

        Parameters
        ----------
        summary : str, optional
            Printed instead of ``"<text>: done"``.

        Returns
        -------
        float
        """
        if self._thread is None:
            return 0.0
        self._stop.set()
        self._thread.join()
        self._thread = None
        self._detach()
        elapsed = time.perf_counter() - self._t0
        line = summary or f"{self._text}: done"
        line = f"{line} ({elapsed:.1f} s)"
        self._write(("\r\x1b[K" if self.tty else "") + line + "\n")
        return elapsed

    def __enter__(self) -> Ticker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # -- internals -----------------------------------------------------------------------------
    def _attach(self) -> None:
        logger = logging.getLogger("idstlpy")
        self._handler = _LastMessage()
        logger.addHandler(self._handler)
        self._saved_level = logger.level
        if logger.getEffectiveLevel() > logging.INFO:
            logger.setLevel(logging.INFO)
        # The counters are DEBUG records of their own logger, kept from every other handler
        # while the ticker shows them.
        counters = logging.getLogger("idstlpy.progress")
        self._counters = _Counters()
        self._saved_progress = (counters.level, counters.propagate)
        counters.addHandler(self._counters)
        counters.setLevel(logging.DEBUG)
        counters.propagate = False

    def _detach(self) -> None:
        if self._handler is None:
            return
        logger = logging.getLogger("idstlpy")
        logger.removeHandler(self._handler)
        logger.setLevel(self._saved_level)
        self._handler = None
        counters = logging.getLogger("idstlpy.progress")
        if self._counters is not None:
            counters.removeHandler(self._counters)
            self._counters = None
        counters.setLevel(self._saved_progress[0])
        counters.propagate = self._saved_progress[1]

    def _line(self, elapsed: float) -> str:
        detail = self._handler.message if self._handler is not None else ""
        line = f"{self._text}: {elapsed:.0f} s"
        counts = self._counters.text() if self._counters is not None else ""
        if counts:
            line += f" | {counts}"
        if detail:
            line += f" | {detail}"
        return line

    def _run(self) -> None:
        spinner = itertools.cycle("|/-\\")
        next_plain = self.plain_every
        while not self._stop.wait(1.0):
            elapsed = time.perf_counter() - self._t0
            if self.tty:
                self._write(f"\r\x1b[K{next(spinner)} {self._line(elapsed)[:150]}")
            elif elapsed >= next_plain:
                next_plain += self.plain_every
                self._write(f"  {self._line(elapsed)[:200]}\n")

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # closed stream (e.g. a pipe that went away)
            pass


class ProgressBar:
    """``progress(done, total, record)`` for :func:`~idstlpy.batch.run_jobs`: a bar on stderr.

    Parameters
    ----------
    stream : file
    enabled : bool
        False counts but writes nothing.
    width : int
        Characters of the bar.
    """

    def __init__(self, stream: TextIO, enabled: bool, width: int = 30) -> None:
        self.stream = stream
        self.enabled = enabled
        self.width = width
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self.cached = 0
        self.failed = 0

    def __call__(self, done: int, total: int, record: Mapping[str, Any]) -> None:
        """Record one finished job and redraw the bar.

        Parameters
        ----------
        done, total : int
            Jobs finished so far, and in all.
        record : dict
            The job's record.
        """
        if (record.get("timing") or {}).get("cached"):
            self.cached += 1
        if record.get("status") == "error":
            self.failed += 1
        if not self.enabled:
            return
        filled = self.width * done // max(total, 1)
        bar = "#" * filled + "." * (self.width - filled)
        extra = []
        if self.cached:
            extra.append(f"{self.cached} cached")
        if self.failed:
            extra.append(f"{self.failed} failed")
        suffix = f" ({', '.join(extra)})" if extra else ""
        line = f"[{bar}] {done}/{total} jobs, last: {record.get('status')}{suffix}"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == total else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
