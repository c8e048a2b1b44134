"""Argument validation shared by the public constructors (never ``assert``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import DimensionError, InvalidArgumentError, InvalidTypeError


def as_matrix(
    value: Any,
    name: str,
    shape: tuple[int | None, int | None] | None = None,
    *,
    axes: tuple[str, str] | None = None,
    origin: str | None = None,
) -> np.ndarray:
    """Return ``value`` as a finite 2-D float array, checking its shape.

    Parameters
    ----------
    value : array_like
        The matrix.
    name : str
        The argument's name, used in error messages.
    shape : (int or None, int or None), optional
        The expected shape; ``None`` entries accept any size along that axis.
    axes : (str, str), optional
        The axes' symbols (``("n", "m")`` for ``B``): the error then reads
        ``B must have shape (n, m) = (2, *)``.
    origin : str, optional
        Where the fixed sizes come from (``"n = 2 states, from A"``), appended to the error.

    Raises
    ------
    InvalidTypeError
        ``value`` is not numeric.
    DimensionError
        ``value`` is not 2-D or disagrees with ``shape``.
    InvalidArgumentError
        ``value`` holds NaN or inf.
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidTypeError(f"{name} must be a numeric matrix, got {type(value).__name__}") from exc
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    want = _want_shape(shape, axes, origin)
    if arr.ndim != 2:
        hint = ""
        if arr.ndim == 1 and shape is not None and shape[0] is not None and arr.shape[0] == shape[0]:
            hint = (
                f"; a single column is written with shape ({shape[0]}, 1), e.g. np.reshape({name}, (-1, 1))"
            )
        elif arr.ndim == 1 and shape is not None and shape[1] is not None and arr.shape[0] == shape[1]:
            hint = f"; a single row is written with shape (1, {shape[1]}), e.g. np.reshape({name}, (1, -1))"
        raise DimensionError(f"{name} must be a 2-D matrix{want}, got an array with shape {arr.shape}{hint}")
    if shape is not None:
        for axis, (size, got) in enumerate(zip(shape, arr.shape, strict=True)):
            if size is not None and size != got:
                label = f"{axes[axis]} = {size}" if axes else f"expected {size}"
                spec = want.removeprefix(" of shape ") if axes else _fmt_shape(shape)
                raise DimensionError(
                    f"{name} must have shape {spec}, got {arr.shape} (axis {axis} is {got}, {label})"
                )
    if not np.all(np.isfinite(arr)):
        raise InvalidArgumentError(f"{name} contains NaN or inf")
    return arr


def _want_shape(
    shape: tuple[int | None, int | None] | None, axes: tuple[str, str] | None, origin: str | None
) -> str:
    """`` of shape (n, m) = (2, *) (n = 2 states, from A)`` for an error message ("" without axes)."""
    if shape is None or axes is None:
        return ""
    text = f" of shape ({axes[0]}, {axes[1]}) = {_fmt_shape(shape)}"
    return text + (f" ({origin})" if origin else "")


def as_vector(value: Any, name: str, size: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite 1-D float array of the given size."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidTypeError(f"{name} must be a numeric vector, got {type(value).__name__}") from exc
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise DimensionError(f"{name} must be a vector, got an array with shape {arr.shape}")
    if size is not None and arr.shape[0] != size:
        raise DimensionError(f"{name} must have length {size}, got length {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise InvalidArgumentError(f"{name} contains NaN or inf")
    return arr


def as_covariance(value: Any, name: str, size: int | None = None, tol: float = 1e-9) -> np.ndarray:
    """Return ``value`` as a symmetric positive semi-definite matrix (within ``tol``)."""
    cov = as_matrix(value, name, (size, size) if size is not None else None)
    if cov.shape[0] != cov.shape[1]:
        raise DimensionError(f"{name} must be square, got shape {cov.shape}")
    scale = max(1.0, float(np.max(np.abs(cov))) if cov.size else 1.0)
    if not np.allclose(cov, cov.T, atol=tol * scale, rtol=0.0):
        raise InvalidArgumentError(f"{name} must be symmetric, got {cov.tolist()}")
    cov = 0.5 * (cov + cov.T)
    if cov.size and float(np.linalg.eigvalsh(cov)[0]) < -tol * scale:
        raise InvalidArgumentError(
            f"{name} must be positive semi-definite; its smallest eigenvalue is "
            f"{float(np.linalg.eigvalsh(cov)[0]):.3g}"
        )
    return cov


def as_int(value: Any, name: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """Return ``value`` as an ``int`` (integral floats accepted) in ``[minimum, maximum]``.

    Parameters
    ----------
    value : int or float
        The value to check; ``bool`` is rejected, integral floats such as ``3.0`` are accepted.
    name : str
        The argument's name, used in error messages.
    minimum, maximum : int, optional
        Inclusive bounds (none by default).

    Returns
    -------
    int

    Raises
    ------
    InvalidTypeError
        ``value`` is not a number.
    InvalidArgumentError
        ``value`` is not a finite integer or lies outside the bounds.
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidTypeError(f"{name} must be an integer, got {type(value).__name__}")
    # Python ints are unbounded: check them without numpy, which refuses ints beyond int64.
    if isinstance(value, float | np.floating) and not np.isfinite(value):
        raise InvalidArgumentError(f"{name} must be a finite integer, got {value!r}")
    if int(value) != value:
        raise InvalidArgumentError(f"{name} must be a finite integer, got {value!r}")
    out = int(value)
    if minimum is not None and out < minimum:
        raise InvalidArgumentError(f"{name} must be >= {minimum}, got {out}")
    if maximum is not None and out > maximum:
        raise InvalidArgumentError(f"{name} must be <= {maximum}, got {_fmt_int(out)}")
    return out


def _fmt_int(value: int) -> str:
    text = str(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} digits)"


def as_float(
    value: Any,
    name: str,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
) -> float:
    """Return ``value`` as a finite float in ``[low, high]`` (``(low, high]`` if ``low_open``)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidTypeError(f"{name} must be a number, got {type(value).__name__}")
    out = float(value)
    if not np.isfinite(out):
        raise InvalidArgumentError(f"{name} must be finite, got {value!r}")
    if low is not None and (out < low or (low_open and out == low)):
        bound = f"> {low}" if low_open else f">= {low}"
        raise InvalidArgumentError(f"{name} must be {bound}, got {out}")
    if high is not None and out > high:
        raise InvalidArgumentError(f"{name} must be <= {high}, got {out}")
    return out


def _fmt_shape(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"


def as_seed_sequence(seed: Any, name: str = "seed", allow_none: bool = True) -> np.random.SeedSequence:
    """Return ``seed`` (an int >= 0, a SeedSequence or, when allowed, None) as a SeedSequence.

    ``None`` gives fresh entropy (recorded in the sequence's ``entropy``).
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if seed is None and allow_none:
        return np.random.SeedSequence()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        expected = "an int, a SeedSequence or None" if allow_none else "an int or a SeedSequence"
        raise InvalidTypeError(f"{name} must be {expected}, got {type(seed).__name__}")
    if seed < 0:
        raise InvalidArgumentError(f"{name} must be >= 0, got {seed}")
    return np.random.SeedSequence(int(seed))
