"""Fixed-interval smoothing: a filtered result in, a smoothed result out.

Offline analysis may use the whole run: the Rauch-Tung-Striebel smoother
(:mod:`~manualcontrol.estimators.filters.smoothers`) runs backwards over what a filter
stored while it ran and gives, at every sample, the estimate given *all* samples. For
time-varying parameters this removes the lag of the filtered estimate behind the truth
(a random-walk filter's estimate trails a ramp by about ``sqrt(R/Q)`` samples; the
smoothed one does not).

Every filter of the family stores its run as one or more :class:`SmootherBlock`
(``estimate(recording, smoother_inputs=True)``): a joint filter one block, a dual
filter two, smoothed each on its own (a dual filter keeps no cross-covariance between
its state and parameter filters, so their smoothers run independently; that is the
dual arrangement's approximation, as in its forward pass). :func:`smooth` maps the
smoothed block states back to the result's parameter columns, projected onto the
filter's limits (the same estimate projection the filter applied) and reported in
model units. The innovations and health flags stay the filter's: they describe the
forward run. Samples after a divergence that stopped the filter are left as filtered.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators.filters.smoothers import (
    LINK_CROSS,
    LINK_RANDOM_WALK,
    LINK_TRANSITION,
    smoother_work,
)
from manualcontrol.estimators.protocol import EstimationResult

__all__ = ["BLOCK_KINDS", "SmootherBlock", "SmootherInputs", "smooth"]

#: The smoother's numba kernel, imported from its module on first use (PEP 562).
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._smoother_kernels", ("rts_smooth",)
)

FloatArray = NDArray[np.float64]

#: How a block's cross-covariance is known: ``"ekf"`` (``link`` holds the transition
#: Jacobians), ``"ukf"`` (``link`` holds the cross-covariances), ``"random-walk"``
#: (no ``link``: ``F = I``).
BLOCK_KINDS = {"ukf": LINK_CROSS, "ekf": LINK_TRANSITION, "random-walk": LINK_RANDOM_WALK}


def _smoother_pass() -> Any:
    """The RTS pass: the C port where it builds (no numba loaded), else the numba kernel.

    Both give the same bytes (``tests/estimators/test_smoother_native.py``).
    """
    from manualcontrol.estimators.filters import _smoother_native

    lib = _smoother_native.library()
    if lib is None:
        from manualcontrol.estimators.filters._smoother_kernels import rts_smooth

        return rts_smooth
    return functools.partial(_smoother_native.rts_smooth, lib)


@dataclass(frozen=True, eq=False)
class SmootherBlock:
    """One filter's stored run (see :mod:`~manualcontrol.estimators.filters.smoothers`).

    Attributes
    ----------
    kind : {"ekf", "ukf", "random-walk"}
        How the cross-covariance is known (:data:`BLOCK_KINDS`).
    x_filtered, P_filtered : ndarray, shapes (N, n) and (N, n, n)
        Posterior after each sample.
    x_predicted, P_predicted : ndarray, shapes (N, n) and (N, n, n)
        Prior at each sample (the initial belief at sample 0).
    link : ndarray, shape (N, n, n), or None
        Per sample ``k >= 1``: the transition Jacobian from ``k - 1`` (``"ekf"``) or
        the cross-covariance ``cov(x^+_{k-1}, x^-_k)`` (``"ukf"``); None for random walks.
    parameters : Mapping[str, int]
        Parameter name -> index of the block state that holds its internal value.
    states : Mapping[str, int]
        State-trace name -> block state index (for results that record state traces).

    """

    kind: str
    x_filtered: FloatArray
    P_filtered: FloatArray
    x_predicted: FloatArray
    P_predicted: FloatArray
    link: FloatArray | None
    parameters: Mapping[str, int]
    states: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in BLOCK_KINDS:
            raise ValueError(f"kind must be one of {tuple(BLOCK_KINDS)}, got {self.kind!r}")
        N, n = np.shape(self.x_filtered)
        for name in ("P_filtered", "P_predicted"):
            if np.shape(getattr(self, name)) != (N, n, n):
                raise ValueError(f"{name} must have shape {(N, n, n)}")
        if np.shape(self.x_predicted) != (N, n):
            raise ValueError(f"x_predicted must have shape {(N, n)}")
        if self.kind != "random-walk" and np.shape(self.link) != (N, n, n):
            raise ValueError(f"a {self.kind!r} block needs link of shape {(N, n, n)}")

    @classmethod
    def of_trace(
        cls,
        kind: str,
        out: Any,
        link: FloatArray | None,
        parameters: Mapping[str, int],
        states: Mapping[str, int] | None = None,
    ) -> SmootherBlock:
        """The block of a kernel's stored run, read from its output record.

        ``out.x_post``, ``P_post``, ``x_prior`` and ``P_prior``, as
        :func:`~manualcontrol.estimators.shell.trace_arrays` lays them out.
        """
        return cls(
            kind=kind,
            x_filtered=out.x_post,
            P_filtered=out.P_post,
            x_predicted=out.x_prior,
            P_predicted=out.P_prior,
            link=link,
            parameters=parameters,
            states={} if states is None else states,
        )


@dataclass(frozen=True, eq=False)
class SmootherInputs:
    """Everything :func:`smooth` needs besides the result itself.

    ``report_offset``/``report_sign`` turn internal values into reported ones (the
    preview time, see :class:`~manualcontrol.estimators.members.pilot_filter.ParameterMap`);
    ``lower``/``upper`` are the internal limits, per parameter in result order.
    """

    blocks: tuple[SmootherBlock, ...]
    parameter_names: tuple[str, ...]
    report_offset: FloatArray
    report_sign: FloatArray
    lower: FloatArray
    upper: FloatArray

    @classmethod
    def of_report(
        cls, blocks: tuple[SmootherBlock, ...], parameter_names: tuple[str, ...], report: Any
    ) -> SmootherInputs:
        """The inputs of ``blocks``, the report's transform and limits copied from the run.

        ``report`` is a kernel's report record (``offset``, ``sign``, ``lo``, ``hi``: the
        pilot core's ``PilotReport``).
        """
        return cls(
            blocks=blocks,
            parameter_names=parameter_names,
            report_offset=report.offset.copy(),
            report_sign=report.sign.copy(),
            lower=report.lo.copy(),
            upper=report.hi.copy(),
        )


def smooth(result: EstimationResult) -> EstimationResult:
    """The fixed-interval smoothed version of a filtered ``result``.

    Raises
    ------
    ValueError
        If ``result`` kept no smoother inputs (run ``estimate(recording,
        smoother_inputs=True)``, or ``estimate(recording, smooth=True)`` directly), or
        is smoothed already.

    """
    if not isinstance(result, EstimationResult):
        raise TypeError(f"result must be an EstimationResult, got {result!r}")
    if result.smoothed:
        raise ValueError("result is smoothed already")
    inputs: Any = result.smoother_inputs
    if inputs is None:
        raise ValueError(
            f"this {result.estimator!r} result kept no smoother inputs: run "
            "estimate(recording, smoother_inputs=True), or estimate(recording, smooth=True)"
        )
    names = tuple(inputs.parameter_names)
    if names != result.parameter_names:
        raise ValueError("the smoother inputs belong to another model's result")
    mean = np.array(result.mean)
    std = np.array(result.std)
    states = np.array(result.states)
    # the rows the filter ran (a stopped filter repeats its last estimate after that)
    n_rows = len(result)
    if result.health.stopped:
        n_rows = int(np.argmin(result.finite)) if not result.finite.all() else n_rows
    rts_smooth = _smoother_pass()
    for block in inputs.blocks:
        n = block.x_filtered.shape[1]
        x_s = np.zeros((n_rows, n))
        P_s = np.zeros((n_rows, n, n))
        link = block.link if block.link is not None else np.zeros((0, n, n))
        rts_smooth(
            np.ascontiguousarray(block.x_filtered[:n_rows]),
            np.ascontiguousarray(block.P_filtered[:n_rows]),
            np.ascontiguousarray(block.x_predicted[:n_rows]),
            np.ascontiguousarray(block.P_predicted[:n_rows]),
            np.ascontiguousarray(link[:n_rows]) if block.link is not None else link,
            BLOCK_KINDS[block.kind],
            x_s,
            P_s,
            smoother_work(n),
        )
        for name, i in block.parameters.items():
            j = names.index(name)
            value = np.clip(x_s[:, i], inputs.lower[j], inputs.upper[j])
            mean[:n_rows, j] = inputs.report_offset[j] + inputs.report_sign[j] * value
            std[:n_rows, j] = np.sqrt(np.maximum(P_s[:, i, i], 0.0))
        for name, i in block.states.items():
            if name in result.state_names:
                states[:n_rows, result.state_names.index(name)] = x_s[:, i]
    return dataclasses.replace(
        result, mean=mean, std=std, states=states, smoothed=True, smoother_inputs=None
    )
