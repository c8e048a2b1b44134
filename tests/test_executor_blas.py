"""executor/blas.py: the prediction's products on one OpenBLAS thread, the counts restored after."""

from __future__ import annotations

import threading

import pytest

from idstlpy.executor import blas


def _counts() -> list[int]:
    out = []
    for lib in blas._loaded_openblas():
        ctl = blas._controls(lib)
        if ctl is not None:
            out.append(int(ctl[0]()))  # type: ignore[operator]
    return out


def test_single_blas_thread_sets_one_thread_and_restores_the_counts():
    before = _counts()
    with blas.single_blas_thread():
        assert all(c == 1 for c in _counts())
        with blas.single_blas_thread():  # re-entrant: the inner exit restores nothing
            pass
        assert all(c == 1 for c in _counts())
    assert _counts() == before


def test_single_blas_thread_restores_after_an_exception():
    before = _counts()
    with pytest.raises(RuntimeError), blas.single_blas_thread():
        raise RuntimeError("inside")
    assert _counts() == before


def test_single_blas_thread_from_several_threads_restores_once():
    before = _counts()
    gate = threading.Barrier(3)

    def work() -> None:
        with blas.single_blas_thread():
            gate.wait(timeout=10)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert _counts() == before


def test_single_blas_thread_without_openblas_does_nothing(monkeypatch):
    monkeypatch.setattr(blas, "_found", [])
    with blas.single_blas_thread():
        pass
