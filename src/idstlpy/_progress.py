"""Progress of a long computation, for whoever shows it (the command line's ticker).

The library never prints: the loops report their counters (candidates, refutations, the current
plan length, the sampler's iterations) as DEBUG records of the ``idstlpy.progress`` logger, each
carrying the counters as a ``progress`` mapping. Nothing is formatted unless a handler listens
(:class:`idstlpy.cli.progress.Ticker` does while it shows a stage).

This module is a leaf: every layer may import it.
"""

from __future__ import annotations

import logging

__all__ = ["LOGGER", "report"]

LOGGER = logging.getLogger("idstlpy.progress")


def report(**counters: int) -> None:
    """Report the current value of some counters (merged with the earlier ones by a listener)."""
    if LOGGER.isEnabledFor(logging.DEBUG):
        LOGGER.debug("progress", extra={"progress": counters})
