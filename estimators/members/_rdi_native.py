"""The RDI's C port bound to its records: the fast path of ``RDI`` where it builds.

``_rdi_native.c`` is the RDI's compiled path (:func:`~manualcontrol.estimators.members.
_rdi_core.rdi_step`, ``rdi_run`` and what they call) in C, the same numbers bit for bit
(:mod:`~manualcontrol.envs._native`: why, and how it is built).
:func:`library` loads it once a process and checks (:func:`declare`), before its first
use, that its layout and its constants (``CFG_*``, ``SC_*``, divergence codes,
tolerances) are the Python modules' own. :class:`NativeRecords` fills its struct of
pointers from an RDI's records and an output record (every array's dtype, contiguity
and shape checked) and steps one sample or a whole run, where numba's ``rdi_step`` and
``rdi_run`` would. ``_rdi_core.simulate_output`` (a simulation, not the filter) stays
on numba.

The struct points into the records' arrays, so C reads and writes where numba would;
a :class:`NativeRecords` is valid while those arrays are (one reset of the filter).
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.envs._native import (
    array_address,
    check_port,
    native_library,
)

__all__ = ["NativeRecords", "declare", "library", "simulate_output"]

SOURCE = Path(__file__).with_name("_rdi_native.c")
#: The layout version ``rdi_abi()`` returns: the struct below and the C one agree.
ABI = 2
#: Columns of ``scratch.flags`` and ``out.flag`` the C port writes.
N_FLAGS = 6
_CHECKED: dict[int, bool] = {}

_SIZES = ("n_s", "n_p", "size", "store_rows")
_CONFIG = ("cfg", "q", "state_param", "limit", "lo", "hi")
_BELIEF = ("x", "P", "p", "ring_r", "ring_y", "sc")
_SCRATCH_BEFORE = ("H", "R", "r")
_WORK = ("PHt", "S", "L", "K", "M", "T", "log_det")
_SCRATCH_AFTER = ("variance", "gradient", "flags")
_OUT = ("mean", "std", "scalar", "flag", "pinned", "x_prior", "P_prior", "x_post", "P_post")

#: The fields the C port reads as int64 and as bool (one byte); the others are float64.
_INTS = frozenset(("state_param", "limit"))
_BOOLS = frozenset(("flags", "flag", "pinned"))


class _KalmanWork(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _WORK] + [("n_log_det", ctypes.c_int64)]


class _Records(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in _SIZES]
        + [(name, ctypes.c_void_p) for name in (*_CONFIG, *_BELIEF, *_SCRATCH_BEFORE)]
        + [("work", _KalmanWork)]
        + [(name, ctypes.c_void_p) for name in (*_SCRATCH_AFTER, *_OUT)]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators.filters import linalg, monitor
    from manualcontrol.estimators.members import _rdi_core as core

    names = (
        "CFG_DT CFG_LAMBDA CFG_R CFG_SIGN CFG_JITTER CFG_MAX_COV CFG_NA CFG_NB CFG_SIZE "
        "SC_K SC_FROZEN SC_DIV_INDEX SC_DIV_REASON SC_STEPS SC_HELD SC_SIZE"
    ).split()
    return [
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
        monitor.REASON_NONE,
        monitor.REASON_NONFINITE,
        monitor.REASON_COVARIANCE,
        *(getattr(core, name) for name in names),
        N_FLAGS,
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_rdi_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    double, int64, address = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.rdi_step.argtypes = [pointer, double, double, int64]
    lib.rdi_step.restype = None
    lib.rdi_run.argtypes = [pointer, address, address, int64]
    lib.rdi_run.restype = None
    lib.rdi_simulate_output.argtypes = [address, int64, address, int64, double, double, double,
                                        double, address, address, address, address]  # fmt: skip
    lib.rdi_simulate_output.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records)}
    check_port(lib, "rdi", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


def simulate_output(
    lib: ctypes.CDLL, p: np.ndarray, r: np.ndarray, dt: float, lam: int, n_a: int, n_b: int
) -> np.ndarray:
    """``_rdi_core.simulate_output`` in C: the model's output from the input ``r`` alone.

    ``p`` (n, 2 + n_a + n_b) C-contiguous float64, the parameters of every sample; ``r``
    (n,) C-contiguous float64.
    """
    n = r.shape[0]
    n_p = 2 + n_a + n_b
    if r.dtype != np.float64 or not r.flags.c_contiguous or r.ndim != 1:
        raise ValueError(f"r must be C-contiguous float64 of one axis, got {r.dtype} {r.shape}")
    if p.dtype != np.float64 or not p.flags.c_contiguous or p.shape != (n, n_p):
        raise ValueError(
            f"p must be C-contiguous float64 of shape ({n}, {n_p}), got {p.dtype} {p.shape}"
        )
    if not (lam >= 1 and n_a >= 0 and n_b >= 0):
        raise ValueError(f"the RDI's orders must be lam >= 1, n_a, n_b >= 0: {lam}, {n_a}, {n_b}")
    out = np.zeros(n)
    ring_r = np.zeros(n)
    ring_y = np.zeros(n)
    gradient = np.zeros(n_p)
    lib.rdi_simulate_output(
        p.ctypes.data, n_p, r.ctypes.data, n, float(dt), float(lam), float(n_a), float(n_b),
        ring_r.ctypes.data, ring_y.ctypes.data, gradient.ctypes.data, out.ctypes.data,
    )  # fmt: skip
    return out


class NativeRecords:
    """The C struct of one RDI's records and an output record (arrays checked, kept alive).

    ``records`` is ``(config, belief, scratch)`` as ``RDI.reset`` builds them, ``out``
    an ``RDIOutput`` (``RDI._new_output``). The struct points into those arrays: C
    writes where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        config, belief, scratch = records
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n_s = belief.x.shape[0]
        n_p = belief.p.shape[0]
        size = belief.ring_r.shape[0]
        rows = out.x_prior.shape[0]
        n_out = out.mean.shape[0]
        for name, value in (("n_s", n_s), ("n_p", n_p), ("size", size), ("store_rows", rows)):
            setattr(struct, name, int(value))
        if size < 1:
            raise ValueError("the RDI's rings are empty")
        if rows not in (0, n_out):
            raise ValueError(f"the smoother storage has {rows} rows for {n_out} output rows")
        # every shape the C indexing assumes (numba reads them off the arrays)
        shapes = {
            "cfg": (8,), "q": (n_s,), "state_param": (n_s,), "limit": (n_s,), "lo": (n_p,),
            "hi": (n_p,),
            "x": (n_s,), "P": (n_s, n_s), "p": (n_p,), "ring_r": (size,), "ring_y": (size,),
            "sc": (6,),
            "H": (1, n_s), "R": (1, 1), "r": (1,), "variance": (n_p,), "gradient": (n_p,),
            "flags": (N_FLAGS,),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, N_FLAGS), "pinned": (n_out, n_p), "x_prior": (rows, n_s),
            "P_prior": (rows, n_s, n_s), "x_post": (rows, n_s), "P_post": (rows, n_s, n_s),
        }  # fmt: skip
        for record, names in (
            (config, _CONFIG),
            (belief, _BELIEF),
            (scratch, _SCRATCH_BEFORE + _SCRATCH_AFTER),
            (out, _OUT),
        ):
            for name in names:
                setattr(struct, name, self._pointer(name, getattr(record, name), shapes[name]))
        work = scratch.work
        work_shapes = {
            "PHt": (n_s, 1), "S": (1, 1), "L": (1, 1), "K": (n_s, 1), "M": (n_s, 1),
            "T": (n_s, n_s), "log_det": (work.log_det.shape[0],),
        }  # fmt: skip
        for name in _WORK:
            setattr(struct.work, name, self._pointer(name, getattr(work, name), work_shapes[name]))
        struct.work.n_log_det = work.log_det.shape[0]
        # the states' parameter indices and limits index the parameter arrays
        for name, index, low in (("state_param", config.state_param, 0),
                                 ("limit", config.limit, -1)):  # fmt: skip
            if index.size and (index.min() < low or index.max() >= n_p):
                raise ValueError(f"the RDI's {name} indexes outside its {n_p} parameters")
        cfg = config.cfg
        if not (cfg[1] >= 1 and cfg[6] >= 0 and cfg[7] >= 0 and 2 + cfg[6] + cfg[7] == n_p):
            raise ValueError("the RDI's cfg does not match its parameter vector")
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def _pointer(self, name: str, array: Any, shape: tuple) -> int:
        kind = np.int64 if name in _INTS else np.bool_ if name in _BOOLS else np.float64
        return array_address("RDI", name, array, shape, self._keep, kind)

    def run(self, r: np.ndarray, y: np.ndarray) -> None:
        """``rdi_run``: sample ``k`` into output row ``k``."""
        n = y.shape[0]
        for name, array in (("r", r), ("y", y)):
            if array.dtype != np.float64 or not array.flags.c_contiguous or array.shape != (n,):
                raise ValueError(
                    f"{name} must be C-contiguous float64 of shape ({n},), "
                    f"got {array.dtype} {array.shape}"
                )
        if n > self.rows:
            raise ValueError(f"the output record has {self.rows} rows for {n} samples")
        self._lib.rdi_run(self.ref, r.ctypes.data, y.ctypes.data, n)

    def step(self, r_k: float, y_k: float, row: int) -> None:
        """``rdi_step`` on one sample into output row ``row``."""
        if not 0 <= row < self.rows:
            raise ValueError(f"row {row} is outside the output record's {self.rows} rows")
        self._lib.rdi_step(self.ref, r_k, y_k, row)

    def entry(self) -> Any:
        """``rdi_step`` as numba's entry point is called (config, belief, scratch, r, y, row, out).

        Bound to these records and this output record, row 0 (the online one-row
        output): only ``r`` and ``y`` are read from the arguments.
        """
        call, ref = self._lib.rdi_step, self.ref

        def step(*arguments: Any) -> None:
            call(ref, arguments[3], arguments[4], 0)

        return step
