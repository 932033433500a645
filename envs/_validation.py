"""Argument checks shared by every public entry point.

Each check raises a built-in exception type (``ValueError`` or ``TypeError``) whose
message names the argument, shows the value found and says what is allowed, so a
caller can catch ``ValueError`` and a user can fix the call from the message alone.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _describe_values(array: NDArray[Any]) -> str:
    """The entries of a numeric array, short: ``0.1``, ``[0.1, 0.2]``, ``[[0.1]]``."""
    if array.size > 8:
        first = ", ".join(repr(v) for v in array.ravel()[:4].tolist())
        return f"{array.size} values: {first}, ..."
    text = repr(array.tolist())
    return text if len(text) <= 80 else text[:77] + "..."


def check_real(name: str, value: Any) -> float:
    """Return ``value`` as a finite float, or raise naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {_describe(value)}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a finite float that is > 0 (or >= 0 with ``allow_zero``)."""
    value = check_real(name, value)
    if value < 0.0 or (value == 0.0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {bound}, got {value!r}")
    return value


def check_range(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> float:
    """Return ``value`` as a finite float inside the given interval."""
    value = check_real(name, value)
    too_low = low is not None and (value < low if low_inclusive else value <= low)
    too_high = high is not None and (value > high if high_inclusive else value >= high)
    if too_low or too_high:
        left = "[" if low_inclusive else "("
        right = "]" if high_inclusive else ")"
        low_text = "-inf" if low is None else f"{low:g}"
        high_text = "inf" if high is None else f"{high:g}"
        raise ValueError(f"{name} must lie in {left}{low_text}, {high_text}{right}, got {value!r}")
    return value


#: The most samples a duration may hold: a day at 1 kHz, 0.8 GB a signal.
MAX_SAMPLES = 10**8


def check_duration(name: str, value: float, dt: float) -> float:
    """A duration of at least one sample of ``dt`` and at most :data:`MAX_SAMPLES`.

    Both are already checked > 0; a ``dt`` longer than the duration is refused, as is a
    duration whose arrays would not fit in a computer's memory.
    """
    if value < dt * (1.0 - 1e-9):
        raise ValueError(f"{name} must hold at least one sample (dt = {dt:g} s), got {value!r} s")
    if value / dt > MAX_SAMPLES:
        raise ValueError(
            f"{name} = {value:g} s holds {value / dt:.3g} samples of dt = {dt:g} s, more than "
            f"the {MAX_SAMPLES:.0e} a run is built for (each signal 8 bytes a sample)"
        )
    return value


def check_int(
    name: str, value: Any, *, minimum: int | None = None, maximum: int | None = None
) -> int:
    """Return ``value`` as an int (bools rejected), within ``[minimum, maximum]`` when given."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {_describe(value)}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value!r}")
    return value


def check_bool(name: str, value: Any) -> bool:
    """Return ``value`` if it is a bool (numpy's too); strings such as ``"False"`` are refused.

    ``bool("False")`` is True, so a truthiness test would silently turn a
    mistyped switch on.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {_describe(value)}")
    return bool(value)


def check_choice(name: str, value: Any, choices: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``choices``; the error lists them all."""
    options = tuple(choices)
    if value not in options:
        listed = ", ".join(repr(option) for option in options)
        raise ValueError(f"{name} must be one of {listed}, got {value!r}")
    return value


def check_vector(
    name: str,
    value: Any,
    *,
    length: int | None = None,
    min_length: int = 0,
    allow_nan: bool = False,
) -> NDArray[np.float64]:
    """Return ``value`` as a 1-D float64 array with finite entries.

    ``allow_nan`` lets NaN through (dropped samples of a measured signal) while
    infinities are still rejected.
    """
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name} must be a 1-D array of numbers, got {_describe(value)}") from error
    if array.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {array.shape}")
    if length is not None and array.shape[0] != length:
        raise ValueError(f"{name} must have length {length}, got length {array.shape[0]}")
    if array.shape[0] < min_length:
        raise ValueError(f"{name} must have at least {min_length} entries, got {array.shape[0]}")
    bad = ~np.isfinite(array)
    if allow_nan:
        bad &= ~np.isnan(array)
    if bad.any():
        index = int(np.flatnonzero(bad)[0])
        kind = "infinite or NaN" if not allow_nan else "infinite"
        raise ValueError(
            f"{name} must be finite, found {int(bad.sum())} {kind} value(s), "
            f"the first at index {index} ({array[index]!r})"
        )
    return array


def check_matrix(name: str, value: Any, shape: tuple[int | None, ...]) -> NDArray[np.float64]:
    """Return ``value`` as a finite float64 array of the expected shape (None = any)."""
    array = np.asarray(value, dtype=np.float64)
    expected = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got non-finite entries")
    return array


def check_action(name: str, value: Any, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """``value`` as a float64 array of ``shape`` (real numbers only), or a clear error.

    Bool, complex, object and string arrays are refused rather than cast: ``True`` or
    ``1+2j`` as a stick deflection is a bug in the caller. Finiteness is the caller's
    check (it knows the bounds).
    """
    expected = f"a real array of shape {shape} (float64)"
    if isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        raise TypeError(f"{name} must be {expected}, got {_describe(value)}")
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name} must be {expected}, got {_describe(value)}") from error
    if array.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be {expected}, got dtype {array.dtype} ({_describe(value)})")
    if array.shape != shape:
        raise ValueError(
            f"{name} must be {expected}, got shape {array.shape} ({_describe_values(array)})"
        )
    return array.astype(np.float64, copy=False)


def step_action(action: Any, k: int, ended: str | None) -> float:
    """The stick ``action[0]`` of an environment's ``step``, as a float.

    ``k`` is the sample the step starts from (negative before ``reset``) and ``ended``
    why the episode ended (None while it runs); either refuses the step with a
    ``RuntimeError``. A float array of shape (1,), the common case, is read at once;
    anything else goes through :func:`check_action`. The value is not bounded here:
    outside the action bound, the caller clips it with :func:`clip_action`.
    """
    if k < 0:
        raise RuntimeError("call reset() before step()")
    if ended is not None:
        raise RuntimeError(f"the episode is over ({ended}); call reset()")
    if type(action) is np.ndarray and action.shape == (1,) and action.dtype.kind == "f":
        return float(action[0])  # the common case, kept free of further calls
    return float(check_action("action", action, (1,))[0])


def clip_action(u: float, bound: float, action: Any) -> float:
    """``u``, found outside ``[-bound, bound]``, clipped to the nearer bound.

    NaN and infinities are refused (``ValueError`` showing ``action``, the value the
    caller was given).
    """
    if u != u or u in (math.inf, -math.inf):
        raise ValueError(f"action must be finite, got {action!r}")
    return bound if u > bound else -bound


def reject_unknown(name: str, given: Iterable[str], known: Iterable[str]) -> None:
    """Raise ``TypeError`` listing keys of ``given`` that are not in ``known``."""
    known_set = set(known)
    unknown = sorted(set(given) - known_set)
    if unknown:
        raise TypeError(
            f"{name} got unknown key(s) {', '.join(map(repr, unknown))}; "
            f"known: {', '.join(map(repr, sorted(known_set)))}"
        )


def check_options(
    options: Any, known: Iterable[str], *, example: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """``reset(options=...)`` as a dict with known keys only (None gives ``{}``).

    ``example`` is the dict the error for a non-dict shows (default
    ``{'realisation': 0}``, the tracking environments' option).
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        shown = {"realisation": 0} if example is None else dict(example)
        raise TypeError(
            f"options must be a dict such as {shown!r} or None, got {_describe(options)}"
        )
    options = dict(options)
    reject_unknown("reset options", options, known)
    return options


def check_times(t: Any) -> NDArray[np.float64]:
    """``t`` as a float64 array of finite times, or a clear error."""
    try:
        times = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"t must be a time in s or an array of times, got {t!r}") from error
    bad = ~np.isfinite(times)
    if bad.any():
        flat = bad.ravel()
        index = int(np.flatnonzero(flat)[0])
        raise ValueError(
            f"t must be finite, found {int(flat.sum())} non-finite time(s), "
            f"the first at flat index {index} ({times.ravel()[index]!r})"
        )
    return times
