"""The RML's C port bound to its records: the fast path of ``RML`` where it builds.

``_rml_native.c`` is the RML filter bank's compiled path (:mod:`~manualcontrol.estimators.
members._rml_core` and what it calls) in C, the same numbers bit for bit
(:mod:`~manualcontrol.envs._native`: why, and how it is built).
:func:`library` loads it once a process and checks (:func:`declare`), before its
first use, that its layout and its constants (``CFG_*``, ``SC_*``, divergence codes,
tolerances, the bank's slot and injection codes, the drift rule's ``_FILLED``) are the
Python modules' own. :class:`NativeRecords` fills its struct of pointers from an RML's
records and an output record (every array's dtype, contiguity and shape checked, the
records' scalar fields copied) and steps one sample, a block in row 0, or a whole run,
where numba's ``bank_step`` and ``bank_step_many`` on a stack of one (every sample into
row 0, or sample ``k`` into row ``k``) would. :class:`NativeBatch` does
``bank_step_many`` on stacked records (:class:`~manualcontrol.estimators.batch.FilterBatch`).

The struct points into the records' arrays, so C reads and writes where numba would
(``config.base[0]`` included, which a causal start sets); a :class:`NativeRecords` is
valid while those arrays are (one reset of the filter).
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

SOURCE = Path(__file__).with_name("_rml_native.c")
#: The layout version ``rml_abi()`` returns: the struct below and the C one agree.
ABI = 1
#: The one-sample step (records, inputs, u, e, row) the online fast path calls
#: (:mod:`~manualcontrol.estimators._online_native`).
ONLINE_STEP = "bank_step"
_CHECKED: dict[int, bool] = {}

_SIZES = (
    "n_c", "n_s", "n_t", "n_m", "n_p", "n_in", "n_terms", "n_chain", "n_branch", "longest",
    "pade_cols", "window", "n_pin", "n_flag", "store_rows", "gradients", "hist_size",
    "substeps", "inject", "has_remnant", "noise_first", "delay_slot",
)  # fmt: skip
_MODEL = (
    "term_coef", "term_var", "term_exp", "term_slot", "chain_num", "chain_den", "chain_pade",
    "chain_offset", "chain_size", "chain_num_length", "chain_den_length", "branch_chain",
    "branch_input", "active", "raw", "raw_grad", "num", "num_grad", "den", "den_grad",
    "pade_value", "pade_slope", "negA", "negA_grad", "C", "C_grad", "d", "d_grad",
)  # fmt: skip
#: BankConfig's arrays as the struct names them (its lo, hi: th_lo, th_hi).
_CONFIG = (
    ("cfg", "cfg"), ("slot", "slot"), ("th_lo", "lo"), ("th_hi", "hi"), ("q", "q"),
    ("remnant", "remnant"), ("estimated", "estimated"), ("base", "base"),
    ("variance_score", "variance_score"), ("spread_cap", "spread_cap"),
    ("drift_rule", "drift_rule"), ("remnant_weight", "remnant_weight"),
)  # fmt: skip
_LINES = ("hist", "extra_slot", "point_in")
_BELIEF = ("th", "P", "X", "PX", "prev_in", "p", "sc", "drift")
_MONITOR = ("buf_u", "buf_e", "pins", "pin_ring", "last_mean", "last_std", "pinned_now")
_REPORT = ("lo", "hi", "offset", "sign")
_SCRATCH_BEFORE = (
    "L", "points", "z", "S", "dz", "dS", "g", "Lam", "LamL", "B", "xi", "Phi", "sub", "Q", "T",
    "H", "r", "R",
)  # fmt: skip
_SCRATCH_AFTER = (
    "xs", "f", "F", "dfdp", "dgdx", "dgdp", "point_p", "in_use", "variance", "scalars",
    "h_dir", "prior",
)  # fmt: skip
_WORK = ("PHt", "S", "L", "K", "M", "T", "log_det")
_OUT = (
    "mean", "std", "scalar", "flag", "pinned", "th_prior", "P_prior", "th_post", "P_post",
    "extra",
)  # fmt: skip


class _KalmanWork(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p) for name in _WORK] + [("n_log_det", ctypes.c_int64)]


class _Records(ctypes.Structure):
    _fields_ = (
        [(name, ctypes.c_int64) for name in _SIZES]
        + [("step", ctypes.c_double)]
        + [
            (name, ctypes.c_void_p)
            for name in (
                *_MODEL,
                *(name for name, _ in _CONFIG),
                *_LINES,
                *_BELIEF,
                *_MONITOR,
                *_REPORT,
                *_SCRATCH_BEFORE,
            )
        ]
        + [("work", _KalmanWork)]
        + [(name, ctypes.c_void_p) for name in (*_SCRATCH_AFTER, *_OUT)]
    )


def _expected_constants() -> list[float]:
    from manualcontrol.estimators import _pilot_core as pilot
    from manualcontrol.estimators.filters import linalg, monitor
    from manualcontrol.estimators.members import _rml_core as core

    names = (
        "CFG_DT CFG_Q2 CFG_R2 CFG_WINDOW CFG_FIRST_WINDOW CFG_FLOOR CFG_JITTER CFG_MAX_COV "
        "CFG_DIMENSIONAL CFG_FIXED_R CFG_FIXED_QE CFG_ERROR_STATE CFG_GAMMA2 CFG_R2_PARAMETER "
        "CFG_SUBSTEPS CFG_SIZE SC_K SC_VAR_U0 SC_VAR_E0 SC_U SC_E SC_FROZEN SC_DIV_INDEX "
        "SC_DIV_REASON SC_DIV_PARAM SC_SIZE"
    ).split()
    return [
        pilot.PAPERS_DT,
        monitor.PIN_FRACTION,
        monitor.NEGATIVE_TOLERANCE,
        linalg.TINY,
        monitor.REASON_NONE,
        monitor.REASON_NONFINITE,
        monitor.REASON_COVARIANCE,
        monitor.REASON_PINNED,
        *(getattr(pilot, name) for name in names),
        core.SLOT_LOG_INTENSITY,
        core.SLOT_LOG_BREAK,
        core.INJECT_INPUT,
        core.INJECT_OUTPUT,
        core._FILLED,
    ]


def library() -> ctypes.CDLL | None:
    """The built C library, declared and checked (:func:`declare`), or None (numba runs)."""
    lib = native_library(SOURCE)
    if lib is None:
        return None
    return declare(lib)


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """Declare the functions of a loaded build of ``_rml_native.c``; check it once.

    Raises ``RuntimeError`` where its struct layout or its constants differ from this
    module's and the Python modules' (a C edit without the Python one, or the reverse).
    """
    if id(lib) in _CHECKED:
        return lib
    pointer = ctypes.POINTER(_Records)
    double, int64, address = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.bank_step.argtypes = [pointer, address, double, double, int64]
    lib.bank_step.restype = None
    for name in ("bank_run", "bank_block"):
        function = getattr(lib, name)
        function.argtypes = [pointer, address, address, address, int64]
        function.restype = None
    lib.bank_step_many.argtypes = [address, address, address, address, address, int64]
    lib.bank_step_many.restype = None
    sizes = {"records_size": ctypes.sizeof(_Records)}
    check_port(lib, "rml", SOURCE.name, ABI, sizes, _expected_constants())
    _CHECKED[id(lib)] = True
    return lib


class NativeRecords:
    """The C struct of one RML's records and an output record (arrays checked, kept alive).

    ``records`` is ``(model, config, lines, belief, monitor, report, scratch)`` as
    ``RML._start`` builds them, ``out`` a ``BankOutput`` (``RML._new_output``).
    The struct points into those arrays: C writes where numba would.
    """

    def __init__(self, lib: ctypes.CDLL, records: tuple, out: Any) -> None:
        model, config, lines, belief, monitor, report, scratch = records
        self._lib = lib
        self._keep: list[np.ndarray] = []
        struct = _Records()
        n_c = scratch.f.shape[0]
        n_m, n_s = belief.X.shape
        n_t = belief.th.shape[0]
        n_p = belief.p.shape[0]
        n_in = belief.prev_in.shape[0]
        n_chain = model.chain_num.shape[0]
        longest = model.num.shape[1]
        rows = out.th_prior.shape[0]
        sizes = {
            "n_c": n_c,
            "n_s": n_s,
            "n_t": n_t,
            "n_m": n_m,
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
            "hist_size": lines.hist.shape[1],
            "substeps": _integer("substeps", config.substeps),
            "inject": _integer("inject", config.inject),
            "has_remnant": int(bool(config.has_remnant)),
            "noise_first": _integer("noise_first", config.noise_first),
            "delay_slot": _integer("delay_slot", lines.delay_slot),
        }
        for name, value in sizes.items():
            setattr(struct, name, int(value))
        struct.step = float(config.step)
        if n_m != 2 * n_t + 1 or n_s != n_c + sizes["has_remnant"]:
            raise ValueError(
                f"the bank has {n_m} members of {n_s} states for {n_t} parameters and "
                f"{n_c} model states: the C port reads 2 n_t + 1 members, n_c (+ 1 remnant)"
            )
        if not 0 <= sizes["delay_slot"] < n_p or sizes["substeps"] < 1 or sizes["hist_size"] < 1:
            raise ValueError("delay_slot, substeps or the delay lines out of the C port's range")
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
            "cfg": None, "slot": (n_t,), "th_lo": (n_t,), "th_hi": (n_t,), "q": (n_t,),
            "remnant": (2,), "estimated": (n_p,), "base": (2,), "variance_score": (n_p,),
            "spread_cap": (n_t,), "drift_rule": (3,), "remnant_weight": (2,),
            "hist": (n_in, sizes["hist_size"]), "extra_slot": (n_in,), "point_in": (n_in,),
            "th": (n_t,), "P": (n_t, n_t), "X": (n_m, n_s), "PX": (n_m, n_s, n_s),
            "prev_in": (n_in,), "p": (n_p,), "sc": None, "drift": (4, n_t),
            "buf_u": (sizes["window"],), "buf_e": (sizes["window"],), "pins": (n_p,),
            "pin_ring": (n_p, sizes["n_pin"]), "last_mean": (n_p,), "last_std": (n_p,),
            "pinned_now": (n_p,), "lo": (n_p,), "hi": (n_p,), "offset": (n_p,),
            "sign": (n_p,),
            "L": (n_t, n_t), "points": (n_m, n_t), "z": (n_m,), "S": (n_m,), "dz": (n_t,),
            "dS": (n_t,), "g": (n_t,), "Lam": (n_t, n_t), "LamL": (n_t, n_t),
            "B": (n_t, n_t), "xi": (1, n_t), "Phi": (n_s, n_s), "sub": (n_s, n_s),
            "Q": (n_s, n_s), "T": (n_s, n_s), "H": (1, n_s), "r": (1,), "R": (1, 1),
            "xs": (n_c,), "f": (n_c,), "F": (n_c, n_c), "dfdp": (n_c, n_p), "dgdx": (n_c,),
            "dgdp": (n_p,), "point_p": (n_p,), "in_use": (n_in,), "variance": (n_p,),
            "scalars": (3,), "h_dir": (n_t,), "prior": (2, n_t),
            "mean": (n_out, n_p), "std": (n_out, n_p), "scalar": (n_out, 3),
            "flag": (n_out, n_flag), "pinned": (n_out, n_p),
            "th_prior": (rows, n_t), "P_prior": (rows, n_t, n_t), "th_post": (rows, n_t),
            "P_post": (rows, n_t, n_t), "extra": (n_out, 3),
        }  # fmt: skip
        if n_flag < 4:
            raise ValueError(f"out.flag needs 4 columns, has {n_flag}")
        for name, field in _CONFIG:
            setattr(struct, name, self._pointer(name, getattr(config, field), shapes[name]))
        for record, names in (
            (model, _MODEL),
            (lines, _LINES),
            (belief, _BELIEF),
            (monitor, _MONITOR),
            (report, _REPORT),
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
        if config.cfg.shape[0] < 17 or belief.sc.shape[0] < 15:
            raise ValueError("cfg or sc shorter than the C port reads")
        error_state = int(config.cfg[11])
        if not 0 <= error_state < n_c:
            raise ValueError(f"cfg's error state {error_state} is not one of {n_c} states")
        self.struct = struct
        self.rows = n_out
        self.ref = ctypes.pointer(struct)

    def _pointer(self, name: str, array: Any, shape: tuple | None) -> int:
        return array_address("RML", name, array, shape, self._keep)

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
        self._lib.bank_run(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def block(self, inputs: np.ndarray, u: np.ndarray, e: np.ndarray) -> None:
        """``bank_step_many`` on a stack of one: every sample, in order, into row 0."""
        n = self._check_samples(inputs, u, e)
        self._lib.bank_block(self.ref, inputs.ctypes.data, u.ctypes.data, e.ctypes.data, n)

    def step(self, inputs_k: np.ndarray, u_k: float, e_k: float) -> None:
        """``bank_step`` on one sample into row 0 (unchecked: the online path's cost)."""
        self._lib.bank_step(self.ref, inputs_k.ctypes.data, u_k, e_k, 0)

    def entry(self, inputs_k: np.ndarray) -> Any:
        """``bank_step`` as numba's entry point is called (records, inputs, u, e, row, out).

        Bound to these records and to ``inputs_k``, whose values the caller sets before
        each call: only ``u`` and ``e`` are read from the arguments (after the seven
        records and the inputs).
        """
        call, ref, address = self._lib.bank_step, self.ref, inputs_k.ctypes.data
        self._keep.append(inputs_k)

        def step(*arguments: Any) -> None:
            call(ref, address, arguments[8], arguments[9], 0)

        return step


def _integer(name: str, value: Any) -> int:
    """A record's integer scalar field (numba types it int64)."""
    if isinstance(value, bool) or int(value) != value:
        raise TypeError(f"the RML's record field {name} must be an integer, got {value!r}")
    return int(value)


class NativeBatch:
    """``bank_step_many`` on stacked records: one struct per filter, views of its row.

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
        self._lib.bank_step_many(
            ctypes.addressof(self._pointers),
            inputs.ctypes.data,
            u.ctypes.data,
            e.ctypes.data,
            active.ctypes.data,
            self.n,
        )
