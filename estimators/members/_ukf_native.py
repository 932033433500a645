"""The unscented filters' C port bound to their records: ``JointUKF``'s and ``DualUKF``'s.

The fast path of the two where it builds.

``_ukf_native.c`` is their compiled path (:mod:`~manualcontrol.estimators.members.
_ukf_core` and what it calls) in C, the same numbers bit for bit
(:mod:`~manualcontrol.envs._native`: why, and how it is built).
:func:`library` loads it once a process and checks (:func:`declare`), before its
first use, that its layout and its constants (``CFG_*``, ``SC_*``, divergence codes,
tolerances, the sensitivity step) are the Python modules' own. :class:`NativeRecords`
fills its struct of pointers from a joint or dual filter's records and an output record
(every array's dtype, contiguity and shape checked) and steps one sample, a block in
row 0, or a whole run, where numba's ``joint_step``/``dual_step`` and the
``*_step_many`` loops on a stack of one (every sample into row 0, or sample ``k`` into
row ``k``) would. :class:`NativeBatch`
does ``*_step_many`` on stacked records
(:class:`~manualcontrol.estimators.batch.FilterBatch`).

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

__all__ = ["NativeBatch", "NativeRecords", "declare", "library"]

SOURCE = Path(__file__).with_name("_ukf_native.c")
#: The layout version ``ukf_abi()`` returns: the struct below and the C one agree.
ABI = 1
#: The one-sample step (records, inputs, u, e, row) the online fast path calls
#: (:mod:`~manualcontrol.estimators._online_native`).
ONLINE_STEP = "ukf_step"
_CHECKED: dict[int, bool] = {}

_SIZES = (
    "n_c", "n", "n_p", "n_in", "n_terms", "n_chain", "n_branch", "longest", "pade_cols",
    "window", "n_pin", "n_flag", "store_rows", "gradients", "dual", "n_t",
)  # fmt: skip
_MODEL = (
    "term_coef", "term_var", "term_exp", "term_slot", "chain_num", "chain_den", "chain_pade",
    "chain_offset", "chain_size", "chain_num_length", "chain_den_length", "branch_chain",
    "branch_input", "active", "raw", "raw_grad", "num", "num_grad", "den", "den_grad",
    "pade_value", "pade_slope", "negA", "negA_grad", "C", "C_grad", "d", "d_grad",
)  # fmt: skip
_CONFIG = ("cfg", "wm", "wc", "q", "slot", "limit")
_BELIEF = ("z", "P", "prev_in", "p", "sc")
_MONITOR = ("buf_u", "buf_e", "pins", "pin_ring", "last_mean", "last_std", "pinned_now")
_REPORT = ("lo", "hi", "offset", "sign")
_WORK = ("L", "X", "Y", "Z", "z", "S", "LS", "Cxz", "K", "xbar", "log_det")
_SCRATCH = (
    "Q", "zero", "R", "r", "z_prev", "cross", "point_p", "f", "F", "dfdp", "dgdx", "dgdp",
    "in_use", "variance", "scalars",
)  # fmt: skip
#: DualTheta's arrays, as the struct names them (``t_*``: where a name repeats another's)
_THETA = (
    ("R", "t_R"), ("D", "D"), ("M", "M"), ("E", "E"), ("zero", "t_zero"),
    ("point_s", "point_s"), ("point_x", "point_x"), ("point_p", "t_point_p"),
)  # fmt: skip
#: UKFOutput's arrays, as the struct names them
_OUT = (
    ("mean", "mean"), ("std", "std"), ("scalar", "scalar"), ("flag", "flag"),
    ("pinned", "pinned"), ("x_prior", "x_prior"), ("P_prior", "P_prior"),
    ("x_post", "x_post"), ("P_post", "P_post"), ("cross", "out_cross"),
    ("x_prior_2", "x_prior_2"), ("P_prior_2", "P_prior_2"), ("x_post_2", "x_post_2"),
    ("P_post_2", "P_post_2"),
)  # fmt: skip


class _Work(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _WORK]


class _Config(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _CONFIG] + [
        ("n_param", ctypes.c_int64),
        ("n_moving", ctypes.c_int64),
    ]


class _Records(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in _SIZES]
        + [(name, ctypes.c_void_p) for name in _MODEL]
        + [("config", _Config), ("estimated", ctypes.c_void_p)]
        + [(name, ctypes.c_void_p) for name in (*_BELIEF, *_MONITOR, *_REPORT)]
        + [("work", _Work)]
        + [(name, ctypes.c_void_p) for name in _SCRATCH]
        + [("t_config", _Config), ("th", ctypes.c_void_p), ("Pp", ctypes.c_void_p)]
        + [("t_work", _Work)]
        + [(field, ctypes.c_void_p) for _, field in _THETA]
        + [(field, ctypes.c_void_p) for _, field in _OUT]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators import _pilot_core as core
    from manualcontrol.estimators.filters import linalg, monitor
    from manualcontrol.estimators.members import _ukf_core

    names = (
        "CFG_DT CFG_Q2 CFG_R2 CFG_WINDOW CFG_FIRST_WINDOW CFG_FLOOR CFG_JITTER CFG_MAX_COV "
        "CFG_FIXED_R CFG_FIXED_QE CFG_ERROR_STATE CFG_GAMMA2 CFG_R2_PARAMETER CFG_SPREAD "
        "CFG_COUNT CFG_SUBSTEPS CFG_SIZE SC_K SC_VAR_U0 SC_VAR_E0 SC_U SC_E SC_FROZEN "
        "SC_DIV_INDEX SC_DIV_REASON SC_DIV_PARAM SC_SIZE"
    ).split()
    return [
        monitor.PIN_FRACTION,
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
        linalg.SEMIDEFINITE_TOLERANCE,
        _ukf_core.SENSITIVITY_STEP,
        monitor.REASON_NONE,
        monitor.REASON_NONFINITE,
        monitor.REASON_COVARIANCE,
        monitor.REASON_PINNED,
        *(getattr(core, name) for name in names),
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_ukf_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    double, int64, address = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.ukf_step.argtypes = [pointer, address, double, double, int64]
    lib.ukf_step.restype = None
    for name in ("ukf_run", "ukf_block"):
        function = getattr(lib, name)
        function.argtypes = [pointer, address, address, address, int64]
        function.restype = None
    lib.ukf_step_many.argtypes = [address, address, address, address, address, int64]
    lib.ukf_step_many.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records)}
    check_port(lib, "ukf", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


def _work_shapes(n: int) -> dict[str, tuple]:
    """unscented_work(n, 1)'s shapes."""
    points = 2 * n + 1
    return {
        "L": (n, n), "X": (points, n), "Y": (points, n), "Z": (points, 1), "z": (1,),
        "S": (1, 1), "LS": (1, 1), "Cxz": (n, 1), "K": (n, 1), "xbar": (n,), "log_det": (1,),
    }  # fmt: skip


class NativeRecords:
    """The C struct of one joint or dual UKF's records and an output record.

    ``records`` is ``(model, config, belief, monitor, report, scratch)`` as
    ``JointUKF._start`` builds them, or those and ``theta`` (``DualUKF._start``); ``out``
    a ``UKFOutput``. Every array is checked and kept alive; the struct points into them,
    so C writes where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        if len(records) == 7:
            model, config, belief, monitor, report, scratch, theta = records
        elif len(records) == 6:
            model, config, belief, monitor, report, scratch = records
            theta = None
        else:
            raise ValueError(f"a UKF has 6 (joint) or 7 (dual) records, got {len(records)}")
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n_c = scratch.f.shape[0]
        n = belief.z.shape[0]
        n_p = belief.p.shape[0]
        n_in = belief.prev_in.shape[0]
        n_chain = model.chain_num.shape[0]
        longest = model.num.shape[1]
        rows = out.x_prior.shape[0]
        n_t = 0 if theta is None else theta.th.shape[0]
        sizes = {
            "n_c": n_c,
            "n": n,
            "n_p": n_p,
            "n_in": n_in,
            "n_terms": model.term_coef.shape[0],
            "n_chain": n_chain,
            "n_branch": model.branch_chain.shape[0],
            "longest": longest,
            "pade_cols": model.pade_value.shape[1],
            "window": monitor.buf_u.shape[0],
            "n_pin": monitor.pin_ring.shape[1],
            "n_flag": out.flag.shape[1],
            "store_rows": rows,
            "gradients": int(bool(model.gradients)),
            "dual": int(theta is not None),
            "n_t": n_t,
        }
        for name, value in sizes.items():
            setattr(struct, name, int(value))
        n_raw = model.raw.shape[0]
        n_terms = sizes["n_terms"]
        pade = sizes["pade_cols"]
        n_flag = sizes["n_flag"]
        n_out = out.mean.shape[0]
        if n_flag < 4:
            raise ValueError(f"out.flag needs 4 columns, has {n_flag}")
        n_second = n_t if theta is not None else out.x_prior_2.shape[1]
        # every shape the C indexing assumes (numba reads them off the arrays)
        shapes = {
            "term_coef": (n_terms,), "term_var": (n_terms, n_p), "term_exp": (n_terms, n_p),
            "term_slot": (n_terms,), "chain_num": (n_chain, 2), "chain_den": (n_chain, 2),
            "chain_pade": (n_chain,), "chain_offset": (n_chain,), "chain_size": (n_chain,),
            "chain_num_length": (n_chain,), "chain_den_length": (n_chain,),
            "branch_chain": (sizes["n_branch"],), "branch_input": (sizes["n_branch"],),
            "active": (n_chain, 3, n_p), "raw": (n_raw,), "raw_grad": (n_raw, n_p),
            "num": (n_chain, longest), "num_grad": (n_chain, longest, n_p),
            "den": (n_chain, longest), "den_grad": (n_chain, longest, n_p),
            "pade_value": (2, pade), "pade_slope": (2, pade), "negA": (n_c,),
            "negA_grad": (n_c, n_p), "C": (n_c,), "C_grad": (n_c, n_p), "d": (n_chain,),
            "d_grad": (n_chain, n_p),
            "z": (n, ), "P": (n, n), "prev_in": (n_in,), "p": (n_p,), "sc": None,
            "buf_u": (sizes["window"],), "buf_e": (sizes["window"],), "pins": (n_p,),
            "pin_ring": (n_p, sizes["n_pin"]), "last_mean": (n_p,), "last_std": (n_p,),
            "pinned_now": (n_p,), "lo": (n_p,), "hi": (n_p,), "offset": (n_p,),
            "sign": (n_p,),
            "Q": (n, n), "zero": (n, n), "R": (1, 1), "r": (1,), "z_prev": (n,),
            "cross": (n, n), "point_p": (n_p,), "f": (n_c,), "F": (n_c, n_c),
            "dfdp": (n_c, n_p), "dgdx": (n_c,), "dgdp": (n_p,), "in_use": (n_in,),
            "variance": (n_p,), "scalars": (3,),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p),
            "x_prior": (rows, n), "P_prior": (rows, n, n), "x_post": (rows, n),
            "P_post": (rows, n, n), "cross_out": (rows, n, n),
            "x_prior_2": (rows, n_second), "P_prior_2": (rows, n_second, n_second),
            "x_post_2": (rows, n_second), "P_post_2": (rows, n_second, n_second),
        }  # fmt: skip
        for record, names in (
            (model, _MODEL),
            (belief, _BELIEF),
            (monitor, _MONITOR),
            (report, _REPORT),
            (scratch, _SCRATCH),
        ):
            for name in names:
                setattr(struct, name, self._pointer(name, getattr(record, name), shapes[name]))
        for name, field in _OUT:
            shape = shapes["cross_out" if name == "cross" else name]
            setattr(struct, field, self._pointer(name, getattr(out, name), shape))
        if n_c < 1 or n < n_c:
            raise ValueError(f"a UKF with {n} states cannot hold {n_c} canonical states")
        self._config(struct.config, config, n, n_p, n_moving_limit=n)
        if config.n_param != n - n_c:
            raise ValueError(f"config.n_param {config.n_param} is not {n} - {n_c} states")
        error_state = config.cfg[11]
        if not 0 <= config.n_param + int(error_state) < n:
            raise ValueError("the error state lies outside the filter")
        self._fill_work(struct.work, scratch.work, n)
        struct.estimated = self._pointer("estimated", config.estimated, (n_p,))
        if belief.sc.shape[0] < 15:
            raise ValueError("sc shorter than the C port reads")
        if theta is not None:
            tc = theta.config
            self._config(struct.t_config, tc, n_t, n_p, n_moving_limit=n_t)
            if tc.n_param != n_t:
                raise ValueError(f"theta config.n_param {tc.n_param} is not its {n_t} states")
            struct.th = self._pointer("th", theta.th, (n_t,))
            struct.Pp = self._pointer("Pp", theta.Pp, (n_t, n_t))
            self._fill_work(struct.t_work, theta.work, n_t)
            theta_shapes = {
                "R": (1, 1), "D": (n, n_t), "M": (n, n_t), "E": (n_t, n_t),
                "zero": (n_t, n_t), "point_s": (n,), "point_x": (n_c,), "point_p": (n_p,),
            }  # fmt: skip
            for name, field in _THETA:
                setattr(
                    struct, field, self._pointer(name, getattr(theta, name), theta_shapes[name])
                )
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def _config(self, target: Any, config: Any, n: int, n_p: int, n_moving_limit: int) -> None:
        """Fill a ``UkfConfig`` (an ``n``-state filter's); its sizes checked."""
        points = 2 * max(n, 1) + 1
        shapes = {
            "cfg": None, "wm": (points,), "wc": (points,), "q": (n,), "slot": (n,),
            "limit": (n,),
        }  # fmt: skip
        for name in _CONFIG:
            setattr(target, name, self._pointer(name, getattr(config, name), shapes[name]))
        if config.cfg.shape[0] < 17:
            raise ValueError("cfg shorter than the C port reads")
        count = int(config.cfg[15])
        if n > 0 and not 0 <= count <= 2 * n + 1:
            raise ValueError(f"cfg's sigma-point count {count} exceeds {2 * n + 1} points")
        n_param, n_moving = int(config.n_param), int(config.n_moving)
        if not 0 <= n_moving <= n_param <= n_moving_limit:
            raise ValueError(f"n_moving {n_moving}, n_param {n_param} for {n} states")
        if ((config.slot[:n_param] < 0) | (config.slot[:n_param] >= n_p)).any():
            raise ValueError("a parameter state's slot lies outside the parameter vector")
        if (config.limit >= n_p).any():
            raise ValueError("a limit entry lies outside the parameter vector")
        target.n_param = n_param
        target.n_moving = n_moving

    def _fill_work(self, target: Any, work: Any, n: int) -> None:
        shapes = _work_shapes(n)
        for name in _WORK:
            setattr(target, name, self._pointer(name, getattr(work, name), shapes[name]))

    def _pointer(self, name: str, array: Any, shape: tuple | None) -> int:
        return array_address("UKF", name, array, shape, self._keep)

    def _check_samples(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray) -> int:
        n = u.shape[0]
        for name, array, shape in (
            ("inputs", inputs, (n, self.struct.n_in)),
            ("u", u, (n,)),
            ("e", e, (n,)),
        ):
            if array.dtype != np.float64 or not array.flags.c_contiguous or array.shape != shape:
                raise ValueError(
                    f"{name} must be C-contiguous float64 of shape {shape}, "
                    f"got {array.dtype} {array.shape}"
                )
        return n

    def run(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray) -> None:
        """A whole run: sample ``k`` into output row ``k``."""
        n = self._check_samples(inputs, u, e)
        if n > self.rows or 0 < self.struct.store_rows < n:
            raise ValueError(f"the output record has {self.rows} rows for {n} samples")
        self._lib.ukf_run(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def block(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray) -> None:
        """``*_step_many`` on a stack of one: every sample, in order, into row 0."""
        n = self._check_samples(inputs, u, e)
        self._lib.ukf_block(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def step(self, inputs_k: np.ndarray, u_k: float, e_k: float) -> None:
        """One step on one sample into row 0 (unchecked: the online path's cost)."""
        self._lib.ukf_step(self.ref, inputs_k.ctypes.data, u_k, e_k, 0)

    def entry(self, inputs_k: np.ndarray) -> Any:
        """The step as numba's entry point is called (records..., inputs, u, e, row, out).

        Bound to these records and to ``inputs_k``, whose values the caller sets before
        each call: only ``u`` and ``e`` are read from the arguments (the fourth and third
        from the end: the joint filter has six records, the dual seven).
        """
        call, ref, address = self._lib.ukf_step, self.ref, inputs_k.ctypes.data
        self._keep.append(inputs_k)

        def step(*arguments: Any) -> None:
            call(ref, address, arguments[-4], arguments[-3], 0)

        return step


class NativeBatch:
    """``*_step_many`` on stacked records: one struct per filter, views of its row.

    ``stacked`` and ``out`` as :class:`~manualcontrol.estimators.batch.FilterBatch`
    stacks them (:func:`~manualcontrol.estimators.filters.batch.stack_records`): filter
    ``i``'s records are row ``i`` of every array, its one-row output row ``i`` of
    ``out``'s.
    """

    def __init__(self, lib: ctypes.CDLL, stacked: tuple, out: Any, n: int) -> None:
        from manualcontrol.estimators.filters.batch import take

        self._lib = lib
        self._filters = [
            NativeRecords(lib, tuple(take(record, i) for record in stacked), take(out, i))
            for i in range(n)
        ]
        self._pointers = (ctypes.c_void_p * n)(
            *(ctypes.addressof(one.struct) for one in self._filters)
        )
        self.n = n

    def step(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray, active: np.ndarray) -> None:
        """Filter ``i`` steps on sample ``i`` where ``active[i]`` (arrays checked by the caller)."""
        self._lib.ukf_step_many(
            ctypes.addressof(self._pointers),
            inputs.ctypes.data,
            u.ctypes.data,
            e.ctypes.data,
            active.ctypes.data,
            self.n,
        )
