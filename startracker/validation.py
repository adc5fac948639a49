"""Input checks shared by every public entry point of the project.

Validation happens once, at the boundary: a public function or method checks its arguments with these helpers and
raises ``TypeError`` (wrong kind of value) or ``ValueError`` (right kind, bad value) with a message that names the
argument and the accepted range. Code that has already validated its inputs calls the array kernels in
:mod:`startracker.kernels` directly, or passes ``validate=False`` to a per-frame method (see ``docs/design.md``).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["as_float_array", "check_positive", "check_real", "check_int", "check_choice", "check_rng", "build_checked"]


def as_float_array(a, name: str, last_dim: int | None = None, ndim: int | None = None) -> np.ndarray:
    """Convert ``a`` to a finite float64 array, raising an error that names ``name``.

    Parameters
    ----------
    a : array_like
    name : str
        Argument name used in error messages.
    last_dim : int, optional
        Required size of the last axis.
    ndim : int, optional
        Required number of dimensions.

    Returns
    -------
    ndarray of float64
        ``a`` itself when it already is a float64 array.

    Raises
    ------
    TypeError
        ``a`` is a string or not numeric.
    ValueError
        Wrong shape, NaN or inf.
    """
    if isinstance(a, (str, bytes)):
        raise TypeError(f"{name} must be a numeric array, got {type(a).__name__}")
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array: {exc}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimension(s), got shape {arr.shape}")
    if last_dim is not None and (arr.ndim == 0 or arr.shape[-1] != last_dim):
        raise ValueError(f"{name} must have last dimension {last_dim}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def check_positive(value, name: str, allow_zero: bool = False) -> float:
    """A finite real number > 0 (``>= 0`` with ``allow_zero``), returned as float.

    Raises ``TypeError`` for a bool or a non-number, ``ValueError`` for NaN, inf or a value out of range.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
    return v


def check_real(value, name: str, lo=None, hi=None, lo_open: bool = False, integer: bool = False) -> float:
    """``value`` as a finite float within ``[lo, hi]`` (``(lo, hi]`` if ``lo_open``); TypeError/ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    if integer and int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value}")
    if hi is not None and v > hi:
        raise ValueError(f"{name} must be <= {hi}, got {value}")
    return v


def check_int(value, name: str, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not a bool) in ``[lo, hi]`` (either bound optional), returned as int."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        if hi is None:
            raise ValueError(f"{name} must be >= {lo}, got {value}")
        if lo is None:
            raise ValueError(f"{name} must be <= {hi}, got {value}")
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
    return v


def check_choice(value, name: str, choices) -> str:
    """One of ``choices`` (compared with ``==``), returned unchanged."""
    if value not in tuple(choices):
        raise ValueError(f"{name} must be one of {tuple(choices)}, got {value!r}")
    return value


def check_rng(rng, name: str = "rng") -> np.random.Generator:
    """A ``numpy.random.Generator`` (every stochastic function draws from the caller's generator)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"{name} must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def build_checked(cls, fields: dict):
    """An instance of the frozen dataclass ``cls`` from values already checked, every field in ``fields``.

    The per-frame results (scenes, detections, samples, motion states) are built from values their producer has
    checked; the dataclass's generated ``__init__`` would set each field through ``object.__setattr__``, one call
    per field, every frame. Here the fields are set at once. ``cls`` must have no ``__post_init__`` and ``fields``
    must hold every field (tests/test_sensor.py and tests/test_scene.py check the per-frame ones).
    """
    obj = object.__new__(cls)
    object.__setattr__(obj, "__dict__", fields)
    return obj
