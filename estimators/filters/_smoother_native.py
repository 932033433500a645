"""The Rauch-Tung-Striebel smoother's C port: the fast path of ``smooth`` where it builds.

``_smoother_native.c`` is :func:`~manualcontrol.estimators.filters._smoother_kernels.
rts_smooth` in C, the same numbers bit for bit (:mod:`~manualcontrol.envs._native`: why,
and how it is built). :func:`library` loads it once a process and checks, before its
first use, that its constants (the link kinds, the prior's loading, ``TINY``) are the
Python modules' own; :func:`rts_smooth` takes the numba kernel's arguments, so the
smoothed twins of every member run without numba where the port builds.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.envs._native import check_port, native_library

__all__ = ["SOURCE", "library", "rts_smooth"]

SOURCE = Path(__file__).with_name("_smoother_native.c")
#: The version ``smoother_abi()`` returns: the arguments below and the C ones agree.
ABI = 1
_CHECKED: dict[int, bool] = {}


def _expected_constants() -> list[float]:
    from manualcontrol.estimators.filters import linalg, smoothers

    return [
        smoothers.LINK_CROSS,
        smoothers.LINK_TRANSITION,
        smoothers.LINK_RANDOM_WALK,
        smoothers.REGULARISATION,
        linalg.TINY,
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked, or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None or id(lib) in _CHECKED:
        return lib
    int64, address = ctypes.c_int64, ctypes.c_void_p
    lib.smoother_rts.argtypes = [int64, int64, *([address] * 5), int64, *([address] * 8)]
    lib.smoother_rts.restype = int64
    check_port(lib, "smoother", SOURCE.name, ABI, {}, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


def _checked(name: str, array: np.ndarray, shape: tuple[int, ...]) -> int:
    if array.dtype != np.float64 or not array.flags.c_contiguous or array.shape != shape:
        raise ValueError(
            f"{name} must be C-contiguous float64 of shape {shape}, got {array.dtype} {array.shape}"
        )
    return array.ctypes.data


def rts_smooth(
    lib: ctypes.CDLL,
    x_filtered: np.ndarray,
    P_filtered: np.ndarray,
    x_predicted: np.ndarray,
    P_predicted: np.ndarray,
    link: np.ndarray,
    kind: int,
    x_smooth: np.ndarray,
    P_smooth: np.ndarray,
    work: Any,
) -> int:
    """The numba kernel's pass in C, its arguments after ``lib`` (every array checked).

    ``link`` is read only for the cross-covariance and transition kinds, where it must
    hold every sample's matrix; ``work`` is :func:`~manualcontrol.estimators.filters.
    smoothers.smoother_work`'s scratch.
    """
    N, n = x_filtered.shape
    run, matrices = (N, n), (N, n, n)
    pointers = [
        _checked("x_filtered", x_filtered, run),
        _checked("P_filtered", P_filtered, matrices),
        _checked("x_predicted", x_predicted, run),
        _checked("P_predicted", P_predicted, matrices),
    ]
    from manualcontrol.estimators.filters.smoothers import LINK_RANDOM_WALK

    if kind == LINK_RANDOM_WALK:
        link_address = link.ctypes.data  # never read
    else:
        link_address = _checked("link", link, matrices)
    outputs = [_checked("x_smooth", x_smooth, run), _checked("P_smooth", P_smooth, matrices)]
    scratch = [_checked(f"work.{name}", getattr(work, name), (n, n)) for name in "CGALDT"]
    return int(lib.smoother_rts(N, n, *pointers, link_address, int(kind), *outputs, *scratch))
