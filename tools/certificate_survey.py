"""A pytest plugin that checks the certificate of every ``infeasible`` the tests' solves return.

Run as ``python -m pytest -p tools.certificate_survey tests/test_x.py``; each result made with
status ``infeasible`` is re-checked by :func:`idstlpy.synthesis.certificates.check_certificate`
and one JSON line per result is appended to ``$CERTIFICATE_SURVEY`` (default
``certificate_survey.jsonl``): the test, the route, whether it verified, the solve's time and the
certificate's share of it.
"""

from __future__ import annotations

import json
import os

import pytest

from idstlpy.synthesis import results
from idstlpy.synthesis.certificates import check_certificate

_current = {"test": ""}


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item: pytest.Item):  # type: ignore[no-untyped-def]
    _current["test"] = item.nodeid
    yield


def _record(result: results.SolveResult) -> None:
    if result.status != "infeasible" or result.stats.time_total <= 0:
        return
    cert = result.certificate
    line = {
        "test": _current["test"],
        "reason": result.reason[:160],
        "time_total": result.stats.time_total,
        "time_certificate": result.stats.time_certificate,
        "route": None if cert is None else cert.get("route"),
        "certified": result.certified,
    }
    if cert is not None:
        check = check_certificate(json.loads(json.dumps(cert)))
        line["check"] = check.summary()
        line["ok"] = check.ok and check.certified
    with open(os.environ.get("CERTIFICATE_SURVEY", "certificate_survey.jsonl"), "a") as fh:
        fh.write(json.dumps(line) + "\n")


_init = results.SolveResult.__init__


def _wrapped(self, *args, **kwargs):  # type: ignore[no-untyped-def]
    _init(self, *args, **kwargs)
    _record(self)


results.SolveResult.__init__ = _wrapped  # type: ignore[method-assign]
