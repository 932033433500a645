"""One online estimator run on many sample streams at once, one compiled call per sample.

:class:`FilterBatch` holds ``n`` filters of one member with the same settings as one
stack of records (:mod:`~manualcontrol.estimators.filters.batch`) and steps all of them
on one sample each with the member's batched kernel (``_step_many_kernel``: its
one-sample step in a compiled loop over the stack). Filter ``i`` gives exactly the
numbers a single estimator of the same settings, reset alike and fed stream ``i``,
gives, bit for bit: the step it runs is the same compiled function on the same types
(or the same step's C port, where the member has one and it builds: the same numbers).

It is what :class:`~manualcontrol.estimators.vector_observer.VectorEstimatorObserver`
steps inside a vector environment; it serves anyone with many streams in step (a
batch of recordings of one length, many simulated pilots).

The members with a batched kernel are the filters on pilot models: the DEKF, the joint
and dual UKFs and the RML filter bank (not its causal choice between two remnant
injections, which decides in Python every few seconds).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import has_kernel
from manualcontrol.envs._validation import check_int
from manualcontrol.estimators.filters.batch import loop_samples, put_record, stack_records
from manualcontrol.estimators.shell import compiled_entry

__all__ = ["FilterBatch", "batched_members"]

FloatArray = NDArray[np.float64]


def batched_members() -> tuple[str, ...]:
    """Names of the members :class:`FilterBatch` can step (for messages)."""
    return ("dekf", "joint-ukf", "dual-ukf", "rml")


class FilterBatch:
    """``n`` copies of an online ``estimator``, stepped together (module docstring).

    Parameters
    ----------
    estimator
        The member whose settings every copy takes (it is not stepped itself; a fresh
        one of the same settings is built). It must start causally: online, no first
        window of data is known at reset.
    n
        Number of copies.
    """

    def __init__(self, estimator: Any, n: int) -> None:
        self.n = check_int("n", n, minimum=1)
        if not has_kernel(type(estimator), "_step_many_kernel"):
            raise ValueError(
                f"estimator {getattr(estimator, 'name', type(estimator).__name__)!r} has no "
                f"batched step; the batched members are {', '.join(batched_members())} "
                "(step others one per stream: an EstimatorObserver per environment)"
            )
        batchable = getattr(estimator, "batchable", None)
        if batchable is not None:
            reason = batchable()
            if reason:
                raise ValueError(reason)
        self._template = estimator.configure()
        self._member = type(estimator)
        self._entry: Any = None
        self._records: Any = None
        self._out: Any = None
        self._initial: Any = None
        keys = tuple(self._template.sample_keys)
        self.sample_keys = keys
        self._input_names = tuple(self._template.internal_model.input_names)
        self._u_at, self._e_at = keys.index("u"), keys.index("e")

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Columns of :meth:`latest`'s arrays."""
        return tuple(self._template.parameter_names)

    @property
    def estimator(self) -> Any:
        """The reset template every copy starts from (never stepped)."""
        return self._template

    def estimated_names(self) -> tuple[str, ...]:
        """The parameters estimated (resolved at :meth:`reset`)."""
        return tuple(self._template.resolved.estimated)

    def reset(self, dt: float) -> None:
        """Start every copy from the initial belief (as ``estimator.reset(dt)``)."""
        template = self._template
        template.reset(dt)
        records, row = template._batch_state()
        self._initial = (records, row)
        self._records = stack_records(records, self.n)
        self._out = stack_records(row, self.n)
        self._entry = None
        # the member's C port of the batched step where it has one and it builds
        native = getattr(template, "_native_batch", None)
        self._native = None if native is None else native(self._records, self._out, self.n)
        self._inputs = np.zeros((self.n, len(self._input_names)))
        self._all = np.ones(self.n, dtype=np.bool_)
        self._rows = np.arange(self.n, dtype=np.int64)
        self._out_rows = np.zeros(self.n, dtype=np.int64)  # one-row outputs

    def reset_copies(self, copies: Sequence[int] | NDArray[np.bool_]) -> None:
        """Start the given copies (indices, or a mask over the copies) afresh.

        A mask is ``n`` booleans (an array or a list of them); anything else is read as
        indices. The initial belief does not depend on the time of the first sample, so a
        copy restarted mid-run is the copy a fresh reset gives.
        """
        self._require_reset()
        records, row = self._initial
        for i in self._copy_indices(copies):
            put_record(self._records, records, i)
            put_record(self._out, row, i)

    def _copy_indices(self, copies: Any) -> list[int]:
        """The indices ``copies`` names: a mask's set flags, or indices checked in range."""
        array = np.asarray(copies)
        if array.dtype == np.bool_:  # a mask, as an array or as a list of bools
            if array.shape != (self.n,):
                raise ValueError(
                    f"copies as a mask must hold one flag per copy ({self.n}), got shape "
                    f"{array.shape}"
                )
            return np.flatnonzero(array).tolist()
        if array.ndim != 1 or (array.size and array.dtype.kind not in "iu"):
            raise ValueError(f"copies must be indices or a mask over the copies, got {copies!r}")
        indices = array.tolist()
        outside = [i for i in indices if not 0 <= i < self.n]
        if outside:
            raise ValueError(f"copies must lie in 0..{self.n - 1}, got {outside}")
        return indices

    def _require_reset(self) -> None:
        if self._records is None:
            raise RuntimeError("the FilterBatch has not been reset; call reset(dt) first")

    def step(
        self,
        signals: Mapping[str, FloatArray],
        active: NDArray[np.bool_] | None = None,
    ) -> None:
        """Feed copy ``i`` the ``i``-th value of every signal in :attr:`sample_keys`.

        ``signals`` maps each key to an array of ``n`` floats (NaN in ``u`` or an input
        marks a dropped sample, as in ``update``). Copies where ``active`` is False are
        not stepped (their estimate stays). The estimates are then in :meth:`latest`.
        """
        self._require_reset()
        missing = [key for key in self.sample_keys if key not in signals]
        if missing:
            raise ValueError(
                f"signals lack {', '.join(map(repr, missing))}; the batch needs "
                f"{', '.join(map(repr, self.sample_keys))}"
            )
        shapes = {key: np.shape(signals[key]) for key in self.sample_keys}
        wrong = {key: shape for key, shape in shapes.items() if shape != (self.n,)}
        if wrong:  # a scalar would broadcast to every copy unnoticed
            raise ValueError(
                f"signals must hold {self.n} values each (one per copy), got "
                + ", ".join(f"{key} {shape}" for key, shape in wrong.items())
            )
        inputs = self._inputs
        for j, name in enumerate(self._input_names):
            inputs[:, j] = signals[name]
        u = loop_samples(signals["u"])
        e = loop_samples(signals["e"])
        for name, values in (("u", u), ("e", e), *zip(self._input_names, inputs.T, strict=True)):
            if np.isinf(values).any():  # NaN marks a dropped sample; inf is a mistake
                copies = np.flatnonzero(np.isinf(values)).tolist()
                raise ValueError(f"signal {name!r} is infinite for copies {copies}")
        # a fresh contiguous copy: the compiled loop reads the mask as contiguous (a
        # strided view, such as every other flag of a longer mask, read the wrong flags)
        active = self._all if active is None else np.array(active, dtype=np.bool_)
        if active.shape != (self.n,):
            raise ValueError(
                f"active must hold {self.n} flags (one per copy), got shape {active.shape}"
            )
        if self._native is not None:
            self._native.step(inputs, u, e, active)
            return
        arguments = (*self._records, inputs, u, e, active, self._rows, self._out_rows, self._out)
        if self._entry is None:
            # read here, on numba's path only: the C port needs neither the kernel nor numba
            self._entry = compiled_entry(self._member._step_many_kernel, arguments)
        else:
            self._entry(*arguments)

    def latest(self) -> tuple[FloatArray, FloatArray]:
        """Views of every copy's means and standard deviations, ``(n, p)`` each.

        Columns in :attr:`parameter_names` order; the next step overwrites them.
        """
        self._require_reset()
        return self._out.mean[:, 0], self._out.std[:, 0]

    def latest_scalars(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Views of every copy's prediction, innovation and its variance, ``(n,)`` each."""
        self._require_reset()
        scalar = self._out.scalar[:, 0]
        return scalar[:, 0], scalar[:, 1], scalar[:, 2]

    def latest_flags(self) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Views of every copy's health flags and pinned parameters.

        Flags ``(n, 4)``: finite, covariance ok, dropped, diverged; pinned ``(n, p)``.
        """
        self._require_reset()
        return self._out.flag[:, 0, :4], self._out.pinned[:, 0]

    def latest_plain(self, i: int, t: float) -> dict[str, Any]:
        """Copy ``i``'s last estimate as a single filter's ``update_plain`` gives it."""
        self._require_reset()
        i = check_int("i", i, minimum=0, maximum=self.n - 1)
        out = self._out
        names = self.parameter_names
        prediction, innovation, variance = out.scalar[i, 0].tolist()
        health = self._template._health_of_row(out.flag[i, 0], out.pinned[i, 0])
        return {
            "t": t,
            "mean": dict(zip(names, out.mean[i, 0].tolist(), strict=True)),
            "std": dict(zip(names, out.std[i, 0].tolist(), strict=True)),
            "innovation": innovation,
            "innovation_variance": variance,
            "prediction": prediction,
            "health": health.as_dict(),
        }
