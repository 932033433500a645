"""The DEKF's C port bound to its records: the fast path of ``DEKF`` where it builds.

``_dekf_native.c`` is the DEKF's compiled path (:mod:`~manualcontrol.estimators.
members._dekf_core` and what it calls) in C, the same numbers bit for bit
(:mod:`~manualcontrol.envs._native`: why, and how it is built).
:func:`library` loads it once a process and checks (:func:`declare`), before its
first use, that its layout and its constants (``CFG_*``, ``SC_*``, divergence codes,
tolerances) are the Python modules' own. :class:`NativeRecords` fills its struct of
pointers from a DEKF's records and an output record (every array's dtype, contiguity
and shape checked) and steps one sample, a block in row 0, or a whole run, where
numba's ``dekf_step`` and ``dekf_step_many`` on a stack of one (every sample into
row 0, or sample ``k`` into row ``k``) would.
:class:`NativeBatch` does ``dekf_step_many`` on stacked records
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

SOURCE = Path(__file__).with_name("_dekf_native.c")
#: The layout version ``dekf_abi()`` returns: the struct below and the C one agree.
ABI = 1
#: The one-sample step (records, inputs, u, e, row) the online fast path calls
#: (:mod:`~manualcontrol.estimators._online_native`).
ONLINE_STEP = "dekf_step"
_CHECKED: dict[int, bool] = {}

_SIZES = (
    "n_c", "n_s", "n_g", "n_t", "n_p", "n_in", "n_terms", "n_chain", "n_branch", "longest",
    "pade_cols", "window", "n_pin", "n_flag", "store_rows", "gradients",
)  # fmt: skip
_MODEL = (
    "term_coef", "term_var", "term_exp", "term_slot", "chain_num", "chain_den", "chain_pade",
    "chain_offset", "chain_size", "chain_num_length", "chain_den_length", "branch_chain",
    "branch_input", "active", "raw", "raw_grad", "num", "num_grad", "den", "den_grad",
    "pade_value", "pade_slope", "negA", "negA_grad", "C", "C_grad", "d", "d_grad",
)  # fmt: skip
_CONFIG = (
    "cfg", "is_dense", "gain_index", "theta_index", "q_state", "q_theta", "state_limit",
    "theta_limit", "estimated",
)  # fmt: skip
_BELIEF = ("x", "P", "th", "Pp", "dx", "prev_in", "p", "sc")
_MONITOR = ("buf_u", "buf_e", "pins", "pin_ring", "last_mean", "last_std", "pinned_now")
_REPORT = ("lo", "hi", "offset", "sign")
_SCRATCH_BEFORE = (
    "F", "f", "dfdp", "dgdx", "dgdp", "M", "H_state", "H_theta", "R_state", "R_theta", "r",
)  # fmt: skip
_SCRATCH_AFTER = ("dxm", "in_use", "variance", "scalars")
_WORK = ("PHt", "S", "L", "K", "M", "T", "log_det")
_OUT = (
    "mean", "std", "scalar", "flag", "pinned", "x_prior", "P_prior", "x_post", "P_post", "Phi",
    "th_prior", "Pp_prior", "th_post", "Pp_post",
)  # fmt: skip


class _KalmanWork(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _WORK] + [("n_log_det", ctypes.c_int64)]


class _Records(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in _SIZES]
        + [
            (name, ctypes.c_void_p)
            for name in (*_MODEL, *_CONFIG, *_BELIEF, *_MONITOR, *_REPORT, *_SCRATCH_BEFORE)
        ]
        + [("state_work", _KalmanWork), ("theta_work", _KalmanWork)]
        + [(name, ctypes.c_void_p) for name in (*_SCRATCH_AFTER, *_OUT)]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators import _pilot_core as core
    from manualcontrol.estimators.filters import linalg, monitor

    names = (
        "CFG_DT CFG_Q2 CFG_R2 CFG_WINDOW CFG_FIRST_WINDOW CFG_FLOOR CFG_JITTER CFG_MAX_COV "
        "CFG_DIMENSIONAL CFG_FIXED_R CFG_FIXED_QE CFG_ERROR_STATE CFG_GAMMA2 CFG_R2_PARAMETER "
        "CFG_SUBSTEPS CFG_SIZE SC_K SC_VAR_U0 SC_VAR_E0 SC_U SC_E SC_FROZEN SC_DIV_INDEX "
        "SC_DIV_REASON SC_DIV_PARAM SC_SIZE"
    ).split()
    return [
        core.PAPERS_DT,
        monitor.PIN_FRACTION,
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
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
    """Declare the functions of a loaded build of ``_dekf_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    double, int64, address = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.dekf_step.argtypes = [pointer, address, double, double, int64]
    lib.dekf_step.restype = None
    for name in ("dekf_run", "dekf_block"):
        function = getattr(lib, name)
        function.argtypes = [pointer, address, address, address, int64]
        function.restype = None
    lib.dekf_step_many.argtypes = [address, address, address, address, address, int64]
    lib.dekf_step_many.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records)}
    check_port(lib, "dekf", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


class NativeRecords:
    """The C struct of one DEKF's records and an output record (arrays checked, kept alive).

    ``records`` is ``(model, config, belief, monitor, report, scratch)`` as
    ``DEKF._start`` builds them, ``out`` a ``DEKFOutput`` (``DEKF._new_output``).
    The struct points into those arrays: C writes where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        model, config, belief, monitor, report, scratch = records
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n_c = scratch.f.shape[0]
        n_s = belief.x.shape[0]
        n_t = belief.th.shape[0]
        n_p = belief.p.shape[0]
        n_in = belief.prev_in.shape[0]
        n_chain = model.chain_num.shape[0]
        longest = model.num.shape[1]
        rows = out.Phi.shape[0]
        sizes = {
            "n_c": n_c,
            "n_s": n_s,
            "n_g": config.gain_index.shape[0],
            "n_t": n_t,
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
        }
        for name, value in sizes.items():
            setattr(struct, name, int(value))
        n_raw = model.raw.shape[0]
        n_terms = sizes["n_terms"]
        pade = sizes["pade_cols"]
        n_flag = sizes["n_flag"]
        n_out = out.mean.shape[0]
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
            "cfg": None, "is_dense": (n_c,), "gain_index": (sizes["n_g"],),
            "theta_index": (n_t,), "q_state": (n_s,), "q_theta": (n_t,),
            "state_limit": (n_s,), "theta_limit": (n_t,), "estimated": (n_p,),
            "x": (n_s,), "P": (n_s, n_s), "th": (n_t,), "Pp": (n_t, n_t), "dx": (n_s, n_t),
            "prev_in": (n_in,), "p": (n_p,), "sc": None,
            "buf_u": (sizes["window"],), "buf_e": (sizes["window"],), "pins": (n_p,),
            "pin_ring": (n_p, sizes["n_pin"]), "last_mean": (n_p,), "last_std": (n_p,),
            "pinned_now": (n_p,), "lo": (n_p,), "hi": (n_p,), "offset": (n_p,),
            "sign": (n_p,),
            "F": (n_c, n_c), "f": (n_c,), "dfdp": (n_c, n_p), "dgdx": (n_c,), "dgdp": (n_p,),
            "M": (n_s, n_s), "H_state": (1, n_s), "H_theta": (1, n_t), "R_state": (1, 1),
            "R_theta": (1, 1), "r": (1,), "dxm": (n_s, n_t), "in_use": (n_in,),
            "variance": (n_p,), "scalars": (3,),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p),
            "x_prior": (rows, n_s), "P_prior": (rows, n_s, n_s), "x_post": (rows, n_s),
            "P_post": (rows, n_s, n_s), "Phi": (rows, n_s, n_s), "th_prior": (rows, n_t),
            "Pp_prior": (rows, n_t, n_t), "th_post": (rows, n_t), "Pp_post": (rows, n_t, n_t),
        }  # fmt: skip
        if n_flag < 4:
            raise ValueError(f"out.flag needs 4 columns, has {n_flag}")
        for record, names in (
            (model, _MODEL),
            (config, _CONFIG),
            (belief, _BELIEF),
            (monitor, _MONITOR),
            (report, _REPORT),
            (scratch, _SCRATCH_BEFORE + _SCRATCH_AFTER),
            (out, _OUT),
        ):
            for name in names:
                setattr(struct, name, self._pointer(name, getattr(record, name), shapes[name]))
        for which, work, n in (("state_work", scratch.state_work, n_s),
                               ("theta_work", scratch.theta_work, n_t)):  # fmt: skip
            target = getattr(struct, which)
            work_shapes = {"PHt": (n, 1), "S": (1, 1), "L": (1, 1), "K": (n, 1), "M": (n, 1),
                           "T": (n, n), "log_det": (work.log_det.shape[0],)}  # fmt: skip
            for name in _WORK:
                setattr(target, name, self._pointer(name, getattr(work, name), work_shapes[name]))
            target.n_log_det = work.log_det.shape[0]
        if config.cfg.shape[0] < 17 or belief.sc.shape[0] < 15:
            raise ValueError("cfg or sc shorter than the C port reads")
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def _pointer(self, name: str, array: Any, shape: tuple | None) -> int:
        return array_address("DEKF", name, array, shape, self._keep)

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
        """A whole run: sample ``k`` into output row ``k`` (``inputs`` ``(n, n_in)``)."""
        n = self._check_samples(inputs, u, e)
        if n > self.rows or 0 < self.struct.store_rows < n:
            raise ValueError(f"the output record has {self.rows} rows for {n} samples")
        self._lib.dekf_run(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def block(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray) -> None:
        """``dekf_step_many`` on a stack of one: every sample, in order, into row 0."""
        n = self._check_samples(inputs, u, e)
        self._lib.dekf_block(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def step(self, inputs_k: np.ndarray, u_k: float, e_k: float) -> None:
        """``dekf_step`` on one sample into row 0 (unchecked: the online path's cost)."""
        self._lib.dekf_step(self.ref, inputs_k.ctypes.data, u_k, e_k, 0)

    def entry(self, inputs_k: np.ndarray) -> Any:
        """``dekf_step`` as numba's entry point is called (records, inputs, u, e, row, out).

        Bound to these records and to ``inputs_k``, whose values the caller sets before
        each call: only ``u`` and ``e`` are read from the arguments.
        """
        call, ref, address = self._lib.dekf_step, self.ref, inputs_k.ctypes.data
        self._keep.append(inputs_k)

        def step(*arguments: Any) -> None:
            call(ref, address, arguments[7], arguments[8], 0)

        return step


class NativeBatch:
    """``dekf_step_many`` on stacked records: one struct per filter, views of its row.

    ``stacked`` and ``out`` as :class:`~manualcontrol.estimators.batch.FilterBatch`
    stacks them (:func:`~manualcontrol.estimators.filters.batch.stack_records`): filter
    ``i``'s records are row ``i`` of every array, its one-row output row ``i`` of
    ``out``'s.
    """

    def __init__(self, lib: ctypes.CDLL, stacked: tuple, out: Any, n: int) -> None:
        from manualcontrol.estimators.filters.batch import take

        self._lib = lib
        self._filters = [
            NativeRecords(
                lib,
                tuple(take(record, i) for record in stacked),
                take(out, i),
            )
            for i in range(n)
        ]
        self._pointers = (ctypes.c_void_p * n)(
            *(ctypes.addressof(one.struct) for one in self._filters)
        )
        self.n = n

    def step(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray, active: np.ndarray) -> None:
        """Filter ``i`` steps on sample ``i`` where ``active[i]`` (arrays checked by the caller)."""
        self._lib.dekf_step_many(
            ctypes.addressof(self._pointers),
            inputs.ctypes.data,
            u.ctypes.data,
            e.ctypes.data,
            active.ctypes.data,
            self.n,
        )
