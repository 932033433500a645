"""Zhao's UKF's C port bound to its records: the fast path of ``ZhaoUKF`` where it builds.

``_zhao_native.c`` is the ZhaoUKF's compiled path (:mod:`~manualcontrol.estimators.
members._zhao_kernels`'s ``zhao_step``/``zhao_run`` and what they call) in C, the same
numbers bit for bit (:mod:`~manualcontrol.envs._native`: why, and how it
is built). :func:`library` loads it once a process and checks (:func:`declare`), before
its first use, that its layout and its constants (``CFG_*``, ``SC_*``, sizes,
divergence codes, tolerances) are the Python modules' own. :class:`NativeRecords`
fills its struct of pointers from a ZhaoUKF's records and an output record (every
array's dtype, contiguity and shape checked) and steps one sample or a whole run,
where numba's ``zhao_step`` and ``zhao_run`` would.

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

__all__ = ["NativeMulti", "NativeRecords", "declare", "library"]

SOURCE = Path(__file__).with_name("_zhao_native.c")
#: The layout version ``zhao_abi()`` returns: the struct below and the C one agree.
ABI = 1
_CHECKED: dict[int, bool] = {}

_SIZES = ("n", "n_t", "n_p", "points", "n_pin", "n_flag", "store_rows", "link_rows")
_CONFIG = ("cfg", "base", "theta_index", "Q", "R", "w_mean", "w_cov", "limit", "estimated")
_BELIEF = ("x", "P", "prev_in", "p", "sc", "link")
_MONITOR = ("pins", "pin_ring", "last_mean", "last_std", "pinned_now")
_REPORT = ("lo", "hi", "offset", "sign")
_WORK = ("L", "X", "Y", "Z", "z", "S", "LS", "Cxz", "K", "xbar", "log_det")
_SCRATCH = ("A", "B", "C", "D", "Bu", "y", "r", "in_use", "variance", "scalars", "point")
_OUT = (
    "mean", "std", "scalar", "flag", "pinned", "predictions", "innovations", "S", "states",
    "x_prior", "P_prior", "x_post", "P_post", "link",
)  # fmt: skip
#: C field names where a record's name is taken by another record's field
_OUT_FIELDS = {"S": "S_out", "link": "link_out"}


class _Records(ctypes.Structure):
    _fields_ = [(name, ctypes.c_int64) for name in _SIZES] + [
        (name, ctypes.c_void_p)
        for name in (
            *_CONFIG,
            *_BELIEF,
            *_MONITOR,
            *_REPORT,
            *_WORK,
            *_SCRATCH,
            *(_OUT_FIELDS.get(name, name) for name in _OUT),
        )
    ]


_FUSION_OUT = (
    "mean", "std", "scalar", "flag", "pinned", "predictions", "innovations", "S", "states",
    "gate", "members",
)  # fmt: skip


class _Fusion(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in ("n_t", "n_p", "n_flag", "feedback")]
        + [("a_short", ctypes.c_double), ("a_long", ctypes.c_double)]
        + [
            (name, ctypes.c_void_p)
            for name in (
                "dead_zone",
                "theta_index",
                "smooth",
                "level",
                "started",
                *(_OUT_FIELDS.get(name, name) for name in _FUSION_OUT),
            )
        ]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators import _pilot_core as pilot
    from manualcontrol.estimators.filters import linalg, monitor
    from manualcontrol.estimators.members import _zhao_core as core

    return [
        monitor.PIN_FRACTION,
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
        linalg.SEMIDEFINITE_TOLERANCE,
        monitor.REASON_NONE,
        monitor.REASON_NONFINITE,
        monitor.REASON_COVARIANCE,
        monitor.REASON_PINNED,
        *(
            getattr(core, name)
            for name in (
                "CFG_VX CFG_H CFG_SUBSTEPS CFG_SPREAD CFG_COUNT CFG_JITTER CFG_MAX_COV CFG_SIZE "
                "N_STATES N_OUTPUTS N_INPUTS"
            ).split()
        ),
        *(
            getattr(pilot, name)
            for name in "SC_K SC_FROZEN SC_DIV_INDEX SC_DIV_REASON SC_DIV_PARAM SC_SIZE".split()
        ),
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_zhao_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    int64, address = ctypes.c_int64, ctypes.c_void_p
    lib.zhao_step.argtypes = [pointer, address, address, int64]
    lib.zhao_step.restype = None
    lib.zhao_run.argtypes = [pointer, address, address, int64]
    lib.zhao_run.restype = None
    lib.multi_step.argtypes = [pointer, pointer, ctypes.POINTER(_Fusion), address, address, int64]
    lib.multi_step.restype = None
    double = ctypes.c_double
    lib.zhao_step_values.argtypes = [pointer, *(double,) * 6, int64]
    lib.zhao_step_values.restype = None
    lib.multi_step_values.argtypes = [
        pointer, pointer, ctypes.POINTER(_Fusion), *(double,) * 6, int64,
    ]  # fmt: skip
    lib.multi_step_values.restype = None
    lib.multi_run.argtypes = [pointer, pointer, ctypes.POINTER(_Fusion), address, address, int64]
    lib.multi_run.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records), "fusion_size": ctypes.sizeof(_Fusion)}
    check_port(lib, "zhao", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


def _pointer(keep: list, name: str, array: Any, shape: tuple) -> int:
    return array_address("ZhaoUKF", name, array, shape, keep)


class NativeRecords:
    """The C struct of one ZhaoUKF's records and an output record (arrays checked, kept alive).

    ``records`` is ``(config, belief, monitor, report, scratch)`` as ``ZhaoUKF._build``
    makes them, ``out`` a ``ZhaoOutput`` (``ZhaoUKF._new_output``). The struct points
    into those arrays: C writes where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        from manualcontrol.estimators import _pilot_core as pilot
        from manualcontrol.estimators.members import _zhao_core as core

        config, belief, monitor, report, scratch = records
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n = belief.x.shape[0]
        n_t = config.theta_index.shape[0]
        n_p = belief.p.shape[0]
        points = scratch.work.X.shape[0]
        n_pin = monitor.pin_ring.shape[1]
        rows = out.x_prior.shape[0]
        n_out = out.mean.shape[0]
        n_flag = out.flag.shape[1]
        link_rows = out.link.shape[0]
        m, n_in, n_x = core.N_OUTPUTS, core.N_INPUTS, core.N_STATES
        if n != n_x + n_t or points != 2 * n + 1:
            raise ValueError(f"{n} states, {n_t} parameters and {points} points do not agree")
        if n_p != 8:
            raise ValueError(f"the driver model has 8 parameters, the records {n_p}")
        if n_flag < 4:
            raise ValueError(f"out.flag needs 4 columns, has {n_flag}")
        if rows not in (0, n_out) or link_rows not in (0, n_out):
            raise ValueError("smoother storage needs one row per output row, or none")
        count = config.cfg[core.CFG_COUNT]
        if not 0 <= count <= points or int(count) != count:
            raise ValueError(f"cfg's sigma-point count {count} is not within 0..{points}")
        theta_index = np.asarray(config.theta_index)
        if theta_index.size and not (0 <= theta_index.min() and theta_index.max() < n_p):
            raise ValueError("theta_index points outside the parameter vector")
        limit = np.asarray(config.limit)
        if limit.size and limit.max() >= n_p:
            raise ValueError("limit points outside the parameter vector")
        sizes = {
            "n": n,
            "n_t": n_t,
            "n_p": n_p,
            "points": points,
            "n_pin": n_pin,
            "n_flag": n_flag,
            "store_rows": rows,
            "link_rows": link_rows,
        }
        for name, value in sizes.items():
            setattr(struct, name, int(value))
        # every shape the C indexing assumes (numba reads them off the arrays)
        shapes = {
            "cfg": (core.CFG_SIZE,), "base": (n_p,), "theta_index": (n_t,), "Q": (n, n),
            "R": (m, m), "w_mean": (points,), "w_cov": (points,), "limit": (n,),
            "estimated": (n_p,),
            "x": (n,), "P": (n, n), "prev_in": (n_in,), "p": (n_p,), "sc": (pilot.SC_SIZE,),
            "link": (n, n),
            "pins": (n_p,), "pin_ring": (n_p, n_pin), "last_mean": (n_p,), "last_std": (n_p,),
            "pinned_now": (n_p,),
            "lo": (n_p,), "hi": (n_p,), "offset": (n_p,), "sign": (n_p,),
            "L": (n, n), "X": (points, n), "Y": (points, n), "Z": (points, m), "z": (m,),
            "S": (m, m), "LS": (m, m), "Cxz": (n, m), "K": (n, m), "xbar": (n,),
            "log_det": (1,),
            "A": (3, 3), "B": (3, n_in), "C": (2, 3), "D": (2, n_in), "Bu": (3,), "y": (3,),
            "r": (m,), "in_use": (n_in,), "variance": (n_p,), "scalars": (3,),
            "point": (n_p,),
        }  # fmt: skip
        out_shapes = {
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p), "predictions": (n_out, m),
            "innovations": (n_out, m), "S": (n_out, m, m), "states": (n_out, n_x),
            "x_prior": (rows, n), "P_prior": (rows, n, n), "x_post": (rows, n),
            "P_post": (rows, n, n), "link": (link_rows, n, n),
        }  # fmt: skip
        keep = self._keep
        for record, names in (
            (config, _CONFIG),
            (belief, _BELIEF),
            (monitor, _MONITOR),
            (report, _REPORT),
            (scratch.work, _WORK),
            (scratch, _SCRATCH),
        ):
            for name in names:
                setattr(struct, name, _pointer(keep, name, getattr(record, name), shapes[name]))
        for name in _OUT:
            address = _pointer(keep, name, getattr(out, name), out_shapes[name])
            setattr(struct, _OUT_FIELDS.get(name, name), address)
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    @staticmethod
    def _check(name: str, array: np.ndarray, shape: tuple) -> None:
        if (
            not isinstance(array, np.ndarray)
            or array.dtype != np.float64
            or not array.flags.c_contiguous
            or array.shape != shape
        ):
            raise ValueError(
                f"{name} must be C-contiguous float64 of shape {shape}, "
                f"got {getattr(array, 'dtype', type(array))} {getattr(array, 'shape', '')}"
            )

    def run(self, inputs: np.ndarray, outputs: np.ndarray) -> None:
        """``zhao_run``: sample ``k`` into output row ``k`` (inputs (n, 4), outputs (n, 2))."""
        n = inputs.shape[0] if isinstance(inputs, np.ndarray) and inputs.ndim == 2 else -1
        self._check("inputs", inputs, (n, 4))
        self._check("outputs", outputs, (n, 2))
        if n > self.rows:
            raise ValueError(f"the output record has {self.rows} rows for {n} samples")
        self._lib.zhao_run(self.ref, inputs.ctypes.data, outputs.ctypes.data, n)

    def step(self, inputs_k: np.ndarray, y_k: np.ndarray) -> None:
        """``zhao_step`` on one sample into row 0 (arrays checked)."""
        self._check("inputs", inputs_k, (4,))
        self._check("outputs", y_k, (2,))
        self._lib.zhao_step(self.ref, inputs_k.ctypes.data, y_k.ctypes.data, 0)

    def entry(self) -> Any:
        """``zhao_step`` as numba's entry point is called (records, inputs, y, row, out).

        Bound to these records: the sample's ``inputs`` and ``y`` (fresh arrays of 4
        and 2 float64 each call, as ``ZhaoUKF._step_sample`` makes them) are read from
        the arguments and passed by value (``zhao_step_values``: a list of six floats
        costs less than two array addresses), unchecked; the row is 0.
        """
        call, ref = self._lib.zhao_step_values, self.ref

        def step(*arguments: Any) -> None:
            call(ref, *arguments[5].tolist(), *arguments[6].tolist(), 0)

        return step


class NativeMulti:
    """The C structs of a multi-UKF: its members' records and outputs, and the fusion.

    ``records`` is ``(slow, fast, fusion, state)`` as ``MultiUKF.reset`` builds them,
    ``out_slow`` and ``out_fast`` the members' ``ZhaoOutput`` and ``out`` the fused
    ``MultiOutput``, all of the same number of rows. C writes where numba would.
    """

    def __init__(
        self, lib: ctypes.CDLL, records: tuple, out_slow: Any, out_fast: Any, out: Any
    ) -> None:
        slow, fast, fusion, state = records
        self._lib = lib
        self._slow = NativeRecords(lib, slow, out_slow)
        self._fast = NativeRecords(lib, fast, out_fast)
        keep = self._keep = [self._slow, self._fast]
        n_out = out.mean.shape[0]
        n_p = out.mean.shape[1]
        n_t = fusion.theta_index.shape[0]
        n_flag = out.flag.shape[1]
        for member in (self._slow, self._fast):
            if member.rows != n_out or member.struct.n_p != n_p or member.struct.n_t != n_t:
                raise ValueError("the members' records and outputs do not match the fusion's")
        if n_flag < 4:
            raise ValueError(f"out.flag needs 4 columns, has {n_flag}")
        theta_index = np.asarray(fusion.theta_index)
        if not np.array_equal(theta_index, np.asarray(slow[0].theta_index)):
            raise ValueError("the fusion's theta_index is not the slow member's")
        struct = _Fusion()
        struct.n_t, struct.n_p, struct.n_flag = n_t, n_p, n_flag
        struct.feedback = int(bool(fusion.feedback))
        struct.a_short = float(fusion.a_short)
        struct.a_long = float(fusion.a_long)
        shapes = {
            "dead_zone": (n_t,), "theta_index": (n_t,), "smooth": (n_t,), "level": (n_t,),
            "started": (1,),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p), "predictions": (n_out, 2),
            "innovations": (n_out, 2), "S": (n_out, 2, 2), "states": (n_out, 3),
            "gate": (n_out, n_t), "members": (n_out, 2 * n_t),
        }  # fmt: skip
        for record, names in (
            (fusion, ("dead_zone", "theta_index")),
            (state, ("smooth", "level", "started")),
            (out, _FUSION_OUT),
        ):
            for name in names:
                address = _pointer(keep, name, getattr(record, name), shapes[name])
                setattr(struct, _OUT_FIELDS.get(name, name), address)
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def run(self, inputs: np.ndarray, outputs: np.ndarray) -> None:
        """``multi_run``: sample ``k`` into row ``k`` of every output."""
        n = inputs.shape[0] if isinstance(inputs, np.ndarray) and inputs.ndim == 2 else -1
        NativeRecords._check("inputs", inputs, (n, 4))
        NativeRecords._check("outputs", outputs, (n, 2))
        if n > self.rows:
            raise ValueError(f"the output records have {self.rows} rows for {n} samples")
        self._lib.multi_run(
            self._slow.ref, self._fast.ref, self.ref, inputs.ctypes.data, outputs.ctypes.data, n
        )

    def step(self, inputs_k: np.ndarray, y_k: np.ndarray) -> None:
        """``multi_step`` on one sample into row 0 (arrays checked)."""
        NativeRecords._check("inputs", inputs_k, (4,))
        NativeRecords._check("outputs", y_k, (2,))
        self._lib.multi_step(
            self._slow.ref, self._fast.ref, self.ref, inputs_k.ctypes.data, y_k.ctypes.data, 0
        )

    def entry(self) -> Any:
        """``multi_step`` as numba's entry point is called (records, inputs, y, row, outs).

        Bound to these records and outputs: the sample's ``inputs`` and ``y`` (fresh
        arrays of 4 and 2 float64 each call, as ``MultiUKF._step_sample`` makes them) are
        read from the arguments and passed by value (``multi_step_values``), unchecked;
        the row is 0.
        """
        call = self._lib.multi_step_values
        slow, fast, ref = self._slow.ref, self._fast.ref, self.ref

        def step(*arguments: Any) -> None:
            call(slow, fast, ref, *arguments[4].tolist(), *arguments[5].tolist(), 0)

        return step
