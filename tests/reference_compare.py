"""Comparing recomputed numbers with numbers recorded on another machine.

The reference tests (``test_*_reference.py``) pin what the executor, the prediction, ``validate``
and ``execute`` computed when they were recorded. Bit-identical results hold between two runs on
one machine (each reference file also checks that), not across CPUs: OpenBLAS picks its kernels
by CPU (``OPENBLAS_CORETYPE``), and a different kernel sums in a different order. So a recorded
float is compared with a tolerance the arithmetic justifies:

- **the tolerance**: ``REL * max|recorded|`` over each array (and over each record's float). An
  array's entries near zero come from cancellations of terms of the array's own size (a
  regression's transition entries of 1e-13 among entries of 30), so their error scales with the
  array's largest entry, not with their own. Measured (2026-11-27, numpy 2.4's OpenBLAS 0.3.31,
  core types Prescott, Nehalem, SandyBridge, Haswell, Zen, SkylakeX): the largest difference is
  3.6e-11 of the array's scale (the particle closure's regressed transitions: a 1000-sample
  least-squares fit, whose conditioning amplifies the summation order); everything else is
  below 1.1e-12. ``REL = 1e-9`` leaves a factor 28 above that and is a million times below what
  a real change moves (one Monte Carlo sample of 1000 moves a rate by 1e-3);
- **the discrete parts exactly**: integer and boolean arrays (modes, success flags, counts), NaN
  positions, shapes and every non-float record field.

``make test`` runs the reference tests a second time under another OpenBLAS core type
(``OPENBLAS_CORETYPE=Prescott``, the oldest x86-64 kernels), so a test tied to one CPU's kernels
fails on this machine first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

#: tolerance relative to the largest magnitude of the recorded array (see the module docstring)
REL = 1e-9


def assert_close_to_reference(got: object, recorded: object, what: str) -> None:
    """Assert ``got`` equals ``recorded`` up to floating-point summation order.

    Parameters
    ----------
    got, recorded : array_like
        Same shape; float arrays within ``REL * max|recorded|`` (NaN where the other is NaN),
        any other dtype exactly.
    what : str
        Named in the failure message.
    """
    a = np.asarray(got)
    b = np.asarray(recorded)
    assert a.shape == b.shape, f"{what}: shape {a.shape} != recorded {b.shape}"
    if a.dtype.kind != "f" or b.dtype.kind != "f":
        assert a.dtype.kind == b.dtype.kind, f"{what}: dtype {a.dtype} != recorded {b.dtype}"
        assert np.array_equal(a, b), f"{what}: differs from the recorded values"
        return
    finite = np.isfinite(b)
    assert np.array_equal(finite, np.isfinite(a)), f"{what}: NaN/inf at other positions"
    assert np.array_equal(a[~finite], b[~finite], equal_nan=True), f"{what}: infinities differ"
    if not finite.any():
        return
    scale = float(np.max(np.abs(b[finite])))
    diff = float(np.max(np.abs(a[finite] - b[finite])))
    assert diff <= REL * scale, f"{what}: differs by {diff:.3g} (tolerance {REL * scale:.3g})"


def assert_records_close(got: object, recorded: object, what: str) -> None:
    """Compare JSON-like records: floats (and float hex strings) with :data:`REL`, the rest exactly.

    Parameters
    ----------
    got, recorded : dict, list, float, str, int, bool or None
        Nested records of the same structure. A string recorded as ``float.hex`` is compared as
        the float it encodes.
    what : str
        Named in the failure message (with the path of the differing field).
    """
    if isinstance(recorded, Mapping):
        assert isinstance(got, Mapping) and set(got) == set(recorded), f"{what}: fields differ"
        for key in recorded:
            assert_records_close(got[key], recorded[key], f"{what}.{key}")
    elif isinstance(recorded, Sequence) and not isinstance(recorded, str):
        assert isinstance(got, Sequence) and len(got) == len(recorded), f"{what}: lengths differ"
        for i, (g, r) in enumerate(zip(got, recorded, strict=True)):
            assert_records_close(g, r, f"{what}[{i}]")
    elif isinstance(recorded, float) or _is_float_hex(recorded):
        g, r = _as_float(got), _as_float(recorded)
        if math.isnan(r):
            assert math.isnan(g), f"{what}: {g} where NaN was recorded"
        else:
            # the records' floats are probabilities: their scale is 1
            assert abs(g - r) <= REL * max(abs(r), 1.0), f"{what}: {g!r} != recorded {r!r}"
    else:
        assert got == recorded, f"{what}: {got!r} != recorded {recorded!r}"


def assert_bit_identical(
    first: Mapping[str, np.ndarray], second: Mapping[str, np.ndarray], what: str
) -> None:
    """Two runs on one machine: the same bits (floats compared as their 64-bit words)."""
    assert set(first) == set(second), f"{what}: keys differ"
    for key, a in first.items():
        b = second[key]
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if a_arr.dtype == np.float64 and b_arr.dtype == np.float64:
            a_arr, b_arr = a_arr.view(np.int64), b_arr.view(np.int64)
        assert np.array_equal(a_arr, b_arr), f"{what}/{key}: two runs on one machine differ"


def _is_float_hex(value: object) -> bool:
    return isinstance(value, str) and (value == "nan" or value.lstrip("-").startswith("0x"))


def _as_float(value: object) -> float:
    if isinstance(value, str):
        return math.nan if value == "nan" else float.fromhex(value)
    assert isinstance(value, (int, float)), f"not a number: {value!r}"
    return float(value)
