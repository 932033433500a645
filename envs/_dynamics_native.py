"""The LPV toolkit's C port bound to its arrays: the fast path of its two kernels.

``_dynamics_native.c`` is the batched matrix exponential and the whole-run LPV
simulation (:func:`~manualcontrol.envs._dynamics_kernels.expm_batch_kernel`,
:func:`~manualcontrol.envs._dynamics_kernels.simulate_lpv_kernel` and what they call)
in C, the same numbers bit for bit (:mod:`~manualcontrol.envs._native`: why, and how it
is built). :func:`library` loads it once a process and checks (:func:`declare`), before
its first use, that its argument lists and the shapes of the tables it reads are this
module's own. :func:`expm_batch` and :func:`simulate_lpv` take the arrays the numba
kernels take (every dtype, contiguity and shape checked before a pointer is passed)
and return what they return.

Importing this module imports neither numba nor the kernels: a process that
discretises and simulates through the C port never loads numba.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._native import check_port, native_library

__all__ = ["declare", "expm_batch", "library", "simulate_lpv"]

FloatArray = NDArray[np.float64]

SOURCE = Path(__file__).with_name("_dynamics_native.c")
#: The version ``dynamics_abi()`` returns: the argument lists below and the C ones agree.
ABI = 1
_CHECKED: dict[int, bool] = {}


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_dynamics_native.c``; check it once.

    Raises ``RuntimeError`` where its argument-list version or the table shapes it
    assumes differ from this module's and :mod:`~manualcontrol.envs._expm`'s (a C edit
    without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    from manualcontrol.envs import _expm

    int64, address, double = ctypes.c_int64, ctypes.c_void_p, ctypes.c_double
    lib.dynamics_expm_batch.argtypes = [
        address, int64, int64, address, address, address, address, double, address, address,
    ]  # fmt: skip
    lib.dynamics_expm_batch.restype = None
    lib.dynamics_simulate_lpv.argtypes = [
        address, int64, address, address, int64, address, int64, address, int64, address,
        int64, int64, int64, int64, address, address, address, int64, address, int64,
        address, int64, address, address, address, address, address,
    ]  # fmt: skip
    lib.dynamics_simulate_lpv.restype = None
    constants = [*_expm._COEFFICIENTS.shape, _expm._ORDERS.shape[0]]
    check_port(lib, "dynamics", SOURCE.name, ABI, {}, constants)
    _CHECKED[id(lib)] = True
    return lib


def _checked(name: str, array: Any, dtype: Any, shape: tuple[int, ...]) -> int:
    """The address of ``array``'s data, once it is C-contiguous ``dtype`` of ``shape``.

    The callers build their arrays so; anything else is a bug that would have the C
    read out of bounds, so it raises instead.
    """
    if (
        not isinstance(array, np.ndarray)
        or array.dtype != np.dtype(dtype)
        or not array.flags.c_contiguous
        or array.shape != shape
    ):
        found = (
            f"{array.dtype} {array.shape}{'' if array.flags.c_contiguous else ', not C-contiguous'}"
            if isinstance(array, np.ndarray)
            else type(array).__name__
        )
        raise ValueError(
            f"{name} must be C-contiguous {np.dtype(dtype).name} of shape {shape} for the "
            f"C port, got {found}"
        )
    return array.ctypes.data if array.size else 0


def expm_batch(
    lib: ctypes.CDLL,
    matrices: FloatArray,
    coefficients: FloatArray,
    theta: FloatArray,
    orders: NDArray[np.int64],
    ell_reciprocal: FloatArray,
    unit_roundoff: float,
) -> FloatArray:
    """``expm_batch_kernel`` in C: ``exp`` of each matrix of ``matrices`` ``(count, n, n)``."""
    if matrices.ndim != 3 or matrices.shape[1] != matrices.shape[2]:
        raise ValueError(f"matrices must have shape (count, n, n), got {matrices.shape}")
    count, n = matrices.shape[0], matrices.shape[1]
    rows, powers = coefficients.shape if coefficients.ndim == 2 else (0, 0)
    n_orders = orders.shape[0] if orders.ndim == 1 else 0
    result = np.empty((count, n, n))
    work = np.empty(9 * n * n + 2 * n)
    lib.dynamics_expm_batch(
        _checked("matrices", matrices, np.float64, (count, n, n)),
        count,
        n,
        _checked("coefficients", coefficients, np.float64, (rows, powers)),
        _checked("theta", theta, np.float64, (n_orders,)),
        _checked("orders", orders, np.int64, (n_orders,)),
        _checked("ell_reciprocal", ell_reciprocal, np.float64, (n_orders,)),
        float(unit_roundoff),
        result.ctypes.data,
        work.ctypes.data,
    )
    return result


def simulate_lpv(
    lib: ctypes.CDLL,
    phi: FloatArray,
    gamma: FloatArray,
    gamma_ramp: FloatArray,
    c: FloatArray,
    d: FloatArray,
    inputs: FloatArray,
    x0: FloatArray,
    delay_inputs: NDArray[np.int64],
    delay_outputs: NDArray[np.int64],
    delay_samples: FloatArray,
    history_pad: int,
    held_state: NDArray[np.bool_],
    history_initial: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """``simulate_lpv_kernel`` in C: states and outputs of the run, the kernel's arguments.

    ``gamma_ramp`` has as many matrices as ``gamma`` (both indexed by ``gamma``'s
    count, as the kernel does); the delay channels' input and output indices must lie
    within ``u`` and ``y``.
    """
    n_samples, n_u = inputs.shape if inputs.ndim == 2 else (0, 0)
    n_x = phi.shape[-1]
    n_y = c.shape[1] if c.ndim == 3 else 0
    n_delay = delay_inputs.shape[0]
    if n_samples == 0:
        # the kernel writes no row; nothing to step
        return np.empty((0, n_x)), np.empty((0, n_y))
    counts = {name: array.shape[0] for name, array in (("phi", phi), ("gamma", gamma),
              ("c", c), ("d", d))}  # fmt: skip
    for name, count in counts.items():
        if count not in (1, n_samples):
            raise ValueError(f"{name} has {count} matrices for {n_samples} samples")
    if np.any((delay_inputs < 0) | (delay_inputs >= n_u)) or np.any(
        (delay_outputs < 0) | (delay_outputs >= n_y)
    ):
        raise ValueError("delay channel indices must lie within the inputs and outputs")
    if history_pad < 0:
        raise ValueError(f"history_pad must be >= 0, got {history_pad}")
    width = history_pad + n_samples
    smooth = np.zeros((n_delay, width))
    held = np.zeros((n_delay, width))
    work = np.zeros(n_u + 2 * n_x + 2 * n_delay)
    states = np.empty((n_samples, n_x))
    outputs = np.empty((n_samples, n_y))
    n_gamma = counts["gamma"]
    lib.dynamics_simulate_lpv(
        _checked("phi", phi, np.float64, (counts["phi"], n_x, n_x)),
        counts["phi"],
        _checked("gamma", gamma, np.float64, (n_gamma, n_x, n_u)),
        _checked("gamma_ramp", gamma_ramp, np.float64, (n_gamma, n_x, n_u)),
        n_gamma,
        _checked("c", c, np.float64, (counts["c"], n_y, n_x)),
        counts["c"],
        _checked("d", d, np.float64, (counts["d"], n_y, n_u)),
        counts["d"],
        _checked("inputs", inputs, np.float64, (n_samples, n_u)),
        n_samples,
        n_x,
        n_u,
        n_y,
        _checked("x0", x0, np.float64, (n_x,)),
        _checked("delay_inputs", delay_inputs, np.int64, (n_delay,)),
        _checked("delay_outputs", delay_outputs, np.int64, (n_delay,)),
        n_delay,
        _checked("delay_samples", delay_samples, np.float64, (n_samples, n_delay)),
        int(history_pad),
        _checked("held_state", held_state, np.bool_, (n_x,)),
        int(bool(history_initial)),
        smooth.ctypes.data,
        held.ctypes.data,
        work.ctypes.data,
        states.ctypes.data,
        outputs.ctypes.data,
    )
    return states, outputs
