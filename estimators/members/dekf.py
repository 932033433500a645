"""Dual Extended Kalman Filter for compensatory and preview tracking.

Popovici, Zaal & Pool (2017) for compensatory tracking, extended to preview tracking by
Vertregt (2020, thesis Part I). Two filters run concurrently (thesis Fig. 2):

* the *state filter* estimates the canonical states of the isolated pilot model and
  the gains that appear only in its output equation (``K_p``, ``K_v``; Popovici
  eq. 38, thesis eq. 40);
* the *parameter filter* estimates the other parameters as random walks (Popovici
  eq. 39: ``omega_nms, zeta_nms, tau_v``; thesis eq. 41 adds ``K_f, omega_f, tau_f*``).

The internal model is built from the pilot structure's one definition
(:mod:`~manualcontrol.estimators.members.internal_model`), delays as Padé approximants
(order 3 by default). Preview time is estimated as the apparent delay
``tau_f* = tau_a - tau_f`` behind the target anticipated by ``tau_a`` (thesis eq. 26);
results report ``tau_f``. Each sample runs the six steps of thesis eqs. 11-25
(:mod:`~manualcontrol.estimators.members._dekf_core`, compiled): parameter prediction, Euler
state prediction, state correction, state limitation, parameter correction with the
total derivative ``G_p^tot`` (eqs. 47-50), parameter limitation.

Settings (:class:`DEKFSettings`): the family's rules for noise, initial values,
covariances and limits (:mod:`~manualcontrol.estimators.members.pilot_filter`, with the papers'
defaults), plus ``total_derivative`` and ``r2_parameter`` below.

Choices where the papers leave room (see also the module docstring of the core)
--------------------------------------------------------------------------------
* ``Phi_s = I + F dt``: the "discrete version of F" (Popovici eq. 18) consistent with
  the Euler prediction of eq. 8 (its exact Jacobian). ``Gamma_s = Gamma_p = I dt``:
  the "discrete input identity matrices" (eq. 19) read as the Euler discretisation
  of the identity noise input of eqs. 2 and 4, so ``Gamma Q Gamma^T = Q dt^2``
  (``noise_input="identity"`` takes ``Gamma = I``; with the papers' Q, 100 % of
  ``K_p`` per sample, that makes every estimate jump by its own size each sample).
* ``total_derivative``: eq. 49 as printed (``"printed"``, the default), or with
  ``dt`` on ``df/dtheta`` (``"dimensional"``, thesis Part II eq. 5.5, the derivative
  of the Euler step); see :data:`TOTAL_DERIVATIVES` for why the default is the
  printed form.
* the state filter's innovation variance is reported (``G_s P_s G_s^T + R``);
  ``r2_parameter`` gives the parameter filter its own ``R`` (thesis Sec. VII-B-1:
  "different measurement covariance matrices R could be used"), the same by default.
* inputs of the prediction are those of the previous sample (Popovici eq. 8's
  ``e_{k-1}``, thesis eq. 49's ``f_{t,a,k-1}, y_{k-1}``; thesis eq. 13 prints
  ``f_{t,k+N_s}``, taken as that misprint).
* sample rates: the papers ran at 100 Hz, and two of their choices are steps of that
  rate. The Euler prediction (eq. 8) errs in proportion to its step (the neuromuscular
  damping comes out about ``omega_nms h / 2`` high), so a sample longer than 0.01 s is
  predicted in Euler substeps of at most 0.01 s
  (:func:`~manualcontrol.estimators._pilot_core.euler_substeps`: two at 50 and 60 Hz;
  faster rates step once a sample, and err less); eq. 49 as printed keeps its 100-Hz
  weight (:data:`TOTAL_DERIVATIVES`). The noise needs nothing: ``R`` is a sample's
  variance and ``Gamma Q Gamma^T = Q dt^2``, so the filters' time constants, about
  ``sqrt(R/Q)`` seconds, are the same at every rate (the reported standard deviations
  are not: every sample counts as new information, so they shrink as the rate rises).
  ``tests/estimators/test_sample_rates.py`` identifies one pilot at 50, 60, 100, 120
  and 1000 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from manualcontrol.envs._lazy import LazyKernel
from manualcontrol.envs._validation import check_choice, check_positive
from manualcontrol.estimators._pilot_core import euler_substeps
from manualcontrol.estimators.filters.kalman import kalman_work
from manualcontrol.estimators.members import _dekf_core as core
from manualcontrol.estimators.members import _dekf_native
from manualcontrol.estimators.members.pilot_filter import CommonArrays, PilotFilter
from manualcontrol.estimators.members.pilot_rules import (
    CE_TYPES,
    INITIAL_VARIANCE_MODES,
    MAX_DELAY_ORDER,
    NOISE_INPUTS,
    PRESETS,
    TABLE_I,
    PilotFilterSettings,
    ResolvedSettings,
)
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.shell import output_arrays, trace_arrays

__all__ = [
    "CE_TYPES",
    "DEKF",
    "INITIAL_VARIANCE_MODES",
    "MAX_DELAY_ORDER",
    "NOISE_INPUTS",
    "PRESETS",
    "TABLE_I",
    "TOTAL_DERIVATIVES",
    "DEKFSettings",
    "ResolvedSettings",
]

#: Forms of thesis eq. 49 (Popovici eq. 44 with the errata's Phi_s).
#:
#: ``"printed"``: ``dx^-_k/dtheta = df/dtheta + Phi_s dx^+_{k-1}/dtheta`` as printed
#: (thesis eq. 49, Part III App. F). ``"dimensional"``: ``df/dtheta dt + Phi_s ...``,
#: the exact derivative of the Euler step (Part II eq. 5.5), dimensionally consistent.
#: The printed form weighs the direct parameter sensitivity by ``1/dt`` at the papers'
#: 100 Hz (x100); at any other rate it keeps that weight, ``1/(0.01 s)``, so that it
#: means the same per second (as printed, a 1-kHz run would weigh it x1000 and a 60-Hz
#: run x60). The default is "printed": it is what the papers ran (the errata reverted
#: to it), and with realistic remnant (30 % of the control power) it keeps the
#: parameters within reach where the dimensional form runs them to their limits (the
#: time-varying compensatory case falls below 50 % one-step VAF). Without remnant the
#: dimensional form is the more accurate (it meets every remnant-free target, the
#: preview time of the single-integrator preview task included, where the printed form
#: trades tau_f* against tau_v); ``tests/estimators/test_dekf_accuracy.py`` checks both.
TOTAL_DERIVATIVES: tuple[str, ...] = ("printed", "dimensional")


@dataclass(frozen=True)
class DEKFSettings(PilotFilterSettings):
    """Settings of the :class:`DEKF` (frozen; vary with its ``replace``).

    Every field of :class:`~manualcontrol.estimators.members.pilot_filter.PilotFilterSettings`,
    plus:

    Parameters
    ----------
    r2_parameter : float or None
        Measurement-noise factor of the parameter filter (> 0); None: ``r2``. A larger
        value makes the parameters average over the remnant (an improvement option).
    total_derivative : {"printed", "dimensional"}
        Form of thesis eq. 49, see :data:`TOTAL_DERIVATIVES`.

    """

    r2_parameter: float | None = None
    total_derivative: str = "printed"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.r2_parameter is not None:
            object.__setattr__(
                self, "r2_parameter", check_positive("r2_parameter", self.r2_parameter)
            )
        check_choice("total_derivative", self.total_derivative, TOTAL_DERIVATIVES)


class DEKF(PilotFilter):
    """Dual Extended Kalman Filter (Popovici et al. 2017; thesis Part I).

    Parameters
    ----------
    settings
        A :class:`DEKFSettings`; keyword arguments replace its fields (or build one).

    Examples
    --------
    >>> from manualcontrol.pilots import Pilot, simulate
    >>> recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", seed=0)
    >>> result = DEKF(model="precision").estimate(recording)
    >>> round(result.final()["K_p"], 1)
    1.5

    """

    name = "dekf"
    settings_type = DEKFSettings
    # the numba kernels, imported (with numba) on first read: the C port runs without them
    _step_kernel = LazyKernel("manualcontrol.estimators.members._dekf_kernels", "dekf_step")
    _step_many_kernel = LazyKernel(
        "manualcontrol.estimators.members._dekf_kernels", "dekf_step_many"
    )
    _native_binding = _dekf_native

    @property
    def settings(self) -> DEKFSettings:
        """The frozen settings."""
        return self._settings

    def _start(self, resolved: ResolvedSettings, common: CommonArrays) -> None:
        settings = self._settings
        internal = self._internal
        names = internal.parameter_names
        n_p = len(names)
        n_c = internal.n_states
        n_g = len(resolved.gains)
        n_t = len(resolved.theta)
        n_s = n_c + n_g
        n_in = len(internal.input_names)
        cfg = common.cfg
        cfg[core.CFG_DIMENSIONAL] = 1.0 if settings.total_derivative == "dimensional" else 0.0
        cfg[core.CFG_SUBSTEPS] = euler_substeps(cfg[core.CFG_DT])
        gain_index = np.array([names.index(n) for n in resolved.gains], dtype=np.int64)
        theta_index = np.array([names.index(n) for n in resolved.theta], dtype=np.int64)
        x = np.zeros(n_s)
        P = np.zeros((n_s, n_s))
        q_state = np.zeros(n_s)
        for i in range(n_c):
            P[i, i] = settings.noise.P0_canonical
        for g, name in enumerate(resolved.gains):
            x[n_c + g] = common.p[names.index(name)]
            P[n_c + g, n_c + g] = resolved.P0[name]
            q_state[n_c + g] = resolved.Q[name]
        state_limit = np.full(n_s, -1, dtype=np.int64)
        state_limit[n_c:] = gain_index
        is_dense = np.zeros(n_c, dtype=np.bool_)
        is_dense[internal.dense_rows] = True
        config = core.DEKFConfig(
            cfg=cfg,
            is_dense=is_dense,
            gain_index=gain_index,
            theta_index=theta_index,
            q_state=q_state,
            q_theta=np.array([resolved.Q[n] for n in resolved.theta], dtype=np.float64),
            state_limit=state_limit,
            theta_limit=theta_index.copy(),
            estimated=common.estimated,
        )
        belief = core.DEKFBelief(
            x=x,
            P=P,
            th=np.array([common.p[j] for j in theta_index], dtype=np.float64),
            Pp=np.diag([resolved.P0[n] for n in resolved.theta]).reshape(n_t, n_t),
            dx=np.zeros((n_s, n_t)),
            prev_in=np.zeros(n_in),
            p=common.p,
            sc=common.sc,
        )
        scratch = core.DEKFScratch(
            F=np.zeros((n_c, n_c)),
            f=np.zeros(n_c),
            dfdp=np.zeros((n_c, n_p)),
            dgdx=np.zeros(n_c),
            dgdp=np.zeros(n_p),
            M=np.zeros((n_s, n_s)),
            H_state=np.zeros((1, n_s)),
            H_theta=np.zeros((1, n_t)),
            R_state=np.zeros((1, 1)),
            R_theta=np.zeros((1, 1)),
            r=np.zeros(1),
            state_work=kalman_work(n_s, 1, log_det=False),
            theta_work=kalman_work(n_t, 1, log_det=False),
            dxm=np.zeros((n_s, n_t)),
            in_use=np.zeros(n_in),
            variance=np.zeros(n_p),
            scalars=np.zeros(3),
        )
        model = internal.kernel((*resolved.gains, *resolved.theta))
        self._records = (model, config, belief, common.monitor, common.report, scratch)
        self._sizes = (n_c, n_s, n_t)

    def _new_output(self, n: int, store: bool) -> core.DEKFOutput:
        n_p = len(self._internal.parameter_names)
        _, n_s, n_t = self._sizes
        rows = n if store else 0
        return core.DEKFOutput(
            **output_arrays(n, n_p),
            **trace_arrays(rows, n_s),
            Phi=np.zeros((rows, n_s, n_s)),
            th_prior=np.zeros((rows, n_t)),
            Pp_prior=np.zeros((rows, n_t, n_t)),
            th_post=np.zeros((rows, n_t)),
            Pp_post=np.zeros((rows, n_t, n_t)),
        )

    def _smoother_inputs(self, out: core.DEKFOutput) -> Any:

        resolved = self.resolved
        n_c, _, n_t = self._sizes
        names = self._internal.parameter_names
        state_block = SmootherBlock.of_trace(
            "ekf", out, out.Phi, {name: n_c + g for g, name in enumerate(resolved.gains)}
        )
        theta_block = SmootherBlock(
            kind="random-walk",
            x_filtered=out.th_post,
            P_filtered=out.Pp_post,
            x_predicted=out.th_prior,
            P_predicted=out.Pp_prior,
            link=None,
            parameters={name: t for t, name in enumerate(resolved.theta)},
        )
        common = self._common
        return SmootherInputs.of_report(
            (state_block, theta_block) if n_t else (state_block,), names, common.report
        )
