"""The Schiess-Roland filter's C port bound to its records: its fast path where it builds.

``_schiess_roland_native.c`` is the filter's compiled path
(:func:`~manualcontrol.estimators.members._schiess_roland_core.sr_step`, ``sr_run`` and
what they call) in C, the same numbers bit for bit
(:mod:`~manualcontrol.envs._native`: why, and how it is built).
:func:`library` loads it once a process and checks (:func:`declare`), before its first
use, that its layout and its constants (the state layout, ``CFG_*``, ``SC_*``, the
Taylor series' columns and limits, divergence codes, tolerances) are the Python
modules' own. :class:`NativeRecords` fills its struct of pointers from a filter's
records and an output record (every array's dtype, contiguity and shape checked) and
steps one sample or a whole run, where numba's ``sr_step`` and ``sr_run`` would.

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

__all__ = ["NativeRecords", "declare", "library"]

SOURCE = Path(__file__).with_name("_schiess_roland_native.c")
#: The layout version ``sr_abi()`` returns: the struct below and the C one agree.
ABI = 1
_CHECKED: dict[int, bool] = {}

_SIZES = ("size", "window", "n_pin", "n_flag", "n_state_cols", "store_rows")
_CONFIG = ("cfg", "gamma", "state_limit", "estimated", "R")
_BELIEF = ("x", "P", "sc", "hist_d", "hist_c", "hist_rate", "q_window", "q_sum", "prev_d", "in_d")
_MONITOR = ("pins", "pin_ring", "last_mean", "last_std", "pinned_now")
_REPORT = ("lo", "hi", "offset", "sign")
_SCRATCH_BEFORE = (
    "terms", "next_terms", "sums", "Z", "J", "Jrho", "Gw", "z", "v", "T1", "U", "H2", "r2",
    "H1", "R1", "r1",
)  # fmt: skip
_WORK = ("PHt", "S", "L", "K", "M", "T", "log_det")
_SCRATCH_AFTER = ("p", "variance", "scalars")
_OUT = (
    "mean", "std", "scalar", "flag", "pinned", "predictions", "innovations", "S", "states",
    "x_prior", "P_prior", "x_post", "P_post", "Phi",
)  # fmt: skip

#: The fields the C port reads as int64 and as bool (one byte); the others are float64.
_INTS = frozenset(("state_limit", "pins", "pin_ring"))
_BOOLS = frozenset(("estimated", "pinned_now", "flag", "pinned"))


class _KalmanWork(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _WORK] + [("n_log_det", ctypes.c_int64)]


class _Records(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in _SIZES]
        + [
            (name, ctypes.c_void_p)
            for name in (*_CONFIG, *_BELIEF, *_MONITOR, *_REPORT, *_SCRATCH_BEFORE)
        ]
        + [("work2", _KalmanWork), ("work1", _KalmanWork)]
        + [(name, ctypes.c_void_p) for name in (*_SCRATCH_AFTER, *_OUT)]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators import _pilot_core as pilot
    from manualcontrol.estimators.filters import linalg, monitor
    from manualcontrol.estimators.members import _schiess_roland_core as core

    pilot_names = "SC_K SC_FROZEN SC_DIV_INDEX SC_DIV_REASON SC_DIV_PARAM SC_SIZE".split()
    names = (
        "N_DYNAMIC N_PARAMETERS N_STATES I_C I_C_RATE I_U I_Y4 I_ETA I_ETA_RATE I_K1 I_TAU1 "
        "I_TAU2 I_TAU3 I_THETA I_ALPHA1 I_ALPHA2 CFG_DT CFG_PLANT_GAIN CFG_PROCESS_NOISE "
        "CFG_JITTER CFG_MAX_COV CFG_BICUBIC CFG_RAMP CFG_ADAPTIVE CFG_MAX_DELAY "
        "CFG_NOISE_FORM CFG_SIZE ADAPTIVE_OFF ADAPTIVE_FULL ADAPTIVE_MODIFIED COL_Z COL_PHI "
        "COL_PARAM COL_E0 COL_RHO COL_W N_COLUMNS _SERIES_REACH _SERIES_TOLERANCE "
        "_SERIES_TERMS _FLOW_SPLIT_CAP"
    ).split()
    return [
        monitor.PIN_FRACTION,
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
        monitor.REASON_NONE,
        monitor.REASON_NONFINITE,
        monitor.REASON_COVARIANCE,
        monitor.REASON_PINNED,
        monitor.REASON_BEYOND_SAMPLE_RATE,
        *(getattr(pilot, name) for name in pilot_names),
        *(getattr(core, name) for name in names),
        *core._PARAM_STATE,
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_schiess_roland_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    double, int64, address = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.sr_step.argtypes = [pointer, double, double, double, int64]
    lib.sr_step.restype = None
    lib.sr_run.argtypes = [pointer, address, address, address, int64]
    lib.sr_run.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records)}
    check_port(lib, "sr", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


class NativeRecords:
    """The C struct of one filter's records and an output record (arrays checked, kept alive).

    ``records`` is ``(config, belief, monitor, report, scratch)`` as
    ``SchiessRoland.reset`` builds them, ``out`` an ``SROutput``
    (``SchiessRoland._new_output``). The struct points into those arrays: C writes
    where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        from manualcontrol.estimators.members import _schiess_roland_core as core

        config, belief, monitor, report, scratch = records
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n, n_z, n_p = core.N_STATES, core.N_DYNAMIC, core.N_PARAMETERS
        columns = core.N_COLUMNS
        size = belief.hist_d.shape[0]
        window = belief.q_window.shape[0]
        n_pin = monitor.pin_ring.shape[1] if monitor.pin_ring.ndim == 2 else -1
        n_out = out.mean.shape[0]
        n_flag = out.flag.shape[1] if out.flag.ndim == 2 else 0
        cols = out.states.shape[1] if out.states.ndim == 2 else 0
        rows = out.x_prior.shape[0]
        sizes = {
            "size": size,
            "window": window,
            "n_pin": n_pin,
            "n_flag": n_flag,
            "n_state_cols": cols,
            "store_rows": rows,
        }
        for name, value in sizes.items():
            setattr(struct, name, int(value))
        if size < 1 or window < 1:
            raise ValueError("the filter's history or adaptive window is empty")
        if n_flag < 4 or cols < n_z + 1:
            raise ValueError("out.flag needs 4 columns and out.states 7")
        if rows not in (0, n_out):
            raise ValueError(f"the smoother storage has {rows} rows for {n_out} output rows")
        # every shape the C indexing assumes (numba reads them off the arrays)
        shapes = {
            "cfg": (10,), "gamma": (n,), "state_limit": (n,), "estimated": (n_p,),
            "R": (2, 2),
            "x": (n,), "P": (n, n), "sc": (15,), "hist_d": (size,), "hist_c": (size,),
            "hist_rate": (size,), "q_window": (window,), "q_sum": (3,), "prev_d": (1,),
            "in_d": (1,),
            "pins": (n_p,), "pin_ring": (n_p, n_pin), "last_mean": (n_p,),
            "last_std": (n_p,), "pinned_now": (n_p,),
            "lo": (n_p,), "hi": (n_p,), "offset": (n_p,), "sign": (n_p,),
            "terms": (columns, n_z), "next_terms": (columns, n_z), "sums": (columns, n_z),
            "Z": (n_z, n_z), "J": (n_z, n_p), "Jrho": (n_z,), "Gw": (n_z,), "z": (n_z,),
            "v": (2 * n_z,), "T1": (n_z, n_p), "U": (n_z, n_z), "H2": (2, n), "r2": (2,),
            "H1": (1, n), "R1": (1, 1), "r1": (1,),
            "p": (n_p,), "variance": (n_p,), "scalars": (3,),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p), "predictions": (n_out, 2),
            "innovations": (n_out, 2), "S": (n_out, 2, 2), "states": (n_out, cols),
            "x_prior": (rows, n), "P_prior": (rows, n, n), "x_post": (rows, n),
            "P_post": (rows, n, n), "Phi": (rows, n, n),
        }  # fmt: skip
        for record, names in (
            (config, _CONFIG),
            (belief, _BELIEF),
            (monitor, _MONITOR),
            (report, _REPORT),
            (scratch, _SCRATCH_BEFORE + _SCRATCH_AFTER),
            (out, _OUT),
        ):
            for name in names:
                setattr(struct, name, self._pointer(name, getattr(record, name), shapes[name]))
        for which, work, m in (("work2", scratch.work2, 2), ("work1", scratch.work1, 1)):
            target = getattr(struct, which)
            work_shapes = {
                "PHt": (n, m), "S": (m, m), "L": (m, m), "K": (n, m), "M": (n, m),
                "T": (n, n), "log_det": (work.log_det.shape[0],),
            }  # fmt: skip
            for name in _WORK:
                setattr(target, name, self._pointer(name, getattr(work, name), work_shapes[name]))
            target.n_log_det = work.log_det.shape[0]
        limit = config.state_limit
        if limit.min() < -1 or limit.max() >= n_p:
            raise ValueError(f"the filter's state_limit indexes outside its {n_p} parameters")
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def _pointer(self, name: str, array: Any, shape: tuple) -> int:
        kind = np.int64 if name in _INTS else np.bool_ if name in _BOOLS else np.float64
        return array_address("Schiess-Roland filter", name, array, shape, self._keep, kind)

    def run(self, d: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
        """``sr_run``: sample ``k`` into output row ``k``."""
        n = u.shape[0]
        for name, array in (("ft", d), ("u", u), ("y", y)):
            if array.dtype != np.float64 or not array.flags.c_contiguous or array.shape != (n,):
                raise ValueError(
                    f"{name} must be C-contiguous float64 of shape ({n},), "
                    f"got {array.dtype} {array.shape}"
                )
        if n > self.rows:
            raise ValueError(f"the output record has {self.rows} rows for {n} samples")
        self._lib.sr_run(self.ref, d.ctypes.data, u.ctypes.data, y.ctypes.data, n)

    def step(self, d_k: float, u_k: float, y_k: float, row: int) -> None:
        """``sr_step`` on one sample into output row ``row``."""
        if not 0 <= row < self.rows:
            raise ValueError(f"row {row} is outside the output record's {self.rows} rows")
        self._lib.sr_step(self.ref, d_k, u_k, y_k, row)

    def entry(self) -> Any:
        """``sr_step`` as numba's entry point is called (five records, d, u, y, row, out).

        Bound to these records and this output record, row 0 (the online one-row
        output): only ``d``, ``u`` and ``y`` are read from the arguments.
        """
        call, ref = self._lib.sr_step, self.ref

        def step(*arguments: Any) -> None:
            call(ref, arguments[5], arguments[6], arguments[7], 0)

        return step
