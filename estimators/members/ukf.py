"""Unscented Kalman filters on the pilot internal models: joint and dual.

The DEKF's two arrangements with the unscented transform in place of Jacobians, on the
same internal model (Padé delays, Euler prediction), with the same noise rules,
initial values, covariances and limits (:mod:`~manualcontrol.estimators.members.pilot_filter`)
and the same report, so the three stand side by side on the same recordings:

* :class:`JointUKF` (``"joint-ukf"``): states and parameters in one augmented filter;
  the filter sees every cross-covariance between them, where the dual arrangement
  drops those between its two filters;
* :class:`DualUKF` (``"dual-ukf"``): a state filter (canonical states and output
  gains) and a parameter filter side by side, as the DEKF (Wan & van der Merwe 2001).

What the papers name as future work: Popovici et al. and Vertregt (thesis Part III App.
I) both propose the unscented filter for its freedom from the Jacobians of the delay
approximation. The algebra is :mod:`~manualcontrol.estimators.filters.unscented`; the
compiled steps are in :mod:`~manualcontrol.estimators.members._ukf_core` (see its docstring
for the order of the augmented state and the dual measurement model).

Smoothing (``estimate(..., smooth=True)``) smooths each parameter marginal as random
walks (Boer & Kenyon's smoother), not the whole augmented state with the unscented RTS
smoother: the canonical states' variances span some twenty orders of magnitude, and
the unscented smoother gain ``C (P^-)^-1`` amplified the rounding of ``C`` and ``P^-``
(two separate point sums) until the smoothed gains ran to their limits on the
time-varying Popovici run, even with relative diagonal loading. The parameters'
marginal dynamics are exactly random walks, so the marginal smoother is the right
recursion for them; it leaves out what the future states say about the parameters
through their cross-covariance, which the filtered marginals already carry forward.

Sample rates: as the DEKF's (its docstring), a sample longer than the papers' 0.01 s is
predicted in Euler substeps of at most 0.01 s
(:func:`~manualcontrol.estimators._pilot_core.euler_substeps`), every sigma point and
the dual filter's differenced sensitivity through the same substeps; the noise rules
keep the filters' time constants in seconds by themselves.

Settings beyond the shared ones: ``sigma_points`` (``"cubature"``, the default: the
third-degree rule of Zhao et al. 2019 Alg. 1, weights ``1/(2N)``, no centre point, all
weights positive so every covariance stays positive semidefinite; or ``"merwe"``, the
scaled set with ``alpha``, ``beta``, ``kappa``), and for the dual filter
``r2_parameter`` as in the DEKF.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from manualcontrol.envs._lazy import LazyKernel
from manualcontrol.envs._validation import check_choice, check_positive, check_real
from manualcontrol.estimators import _pilot_core as pilot_core
from manualcontrol.estimators.filters.unscented import (
    SIGMA_SCHEMES,
    sigma_weights,
    unscented_work,
)
from manualcontrol.estimators.members import _ukf_core as core
from manualcontrol.estimators.members import _ukf_native
from manualcontrol.estimators.members.pilot_filter import CommonArrays, PilotFilter
from manualcontrol.estimators.members.pilot_rules import PilotFilterSettings, ResolvedSettings
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.shell import output_arrays, trace_arrays

__all__ = ["DualUKF", "DualUKFSettings", "JointUKF", "UKFSettings"]

#: Where the numba kernels live, imported (with numba) on first read: the C port runs
#: without them.
_KERNEL_MODULE = "manualcontrol.estimators.members._ukf_kernels"


@dataclass(frozen=True)
class UKFSettings(PilotFilterSettings):
    """Settings of the :class:`JointUKF` (the shared fields, plus the sigma points).

    Parameters
    ----------
    sigma_points : {"cubature", "merwe"}
        Sigma-point rule (:data:`~manualcontrol.estimators.filters.unscented.SIGMA_SCHEMES`).
    alpha, beta, kappa : float
        Merwe scaled set: spread (> 0), prior knowledge (2 for Gaussian) and secondary
        scaling; ignored by the cubature rule.

    """

    sigma_points: str = "cubature"
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_choice("sigma_points", self.sigma_points, SIGMA_SCHEMES)
        object.__setattr__(self, "alpha", check_positive("alpha", self.alpha))
        object.__setattr__(self, "beta", check_real("beta", self.beta))
        object.__setattr__(self, "kappa", check_real("kappa", self.kappa))


@dataclass(frozen=True)
class DualUKFSettings(UKFSettings):
    """Settings of the :class:`DualUKF`: those of :class:`UKFSettings` and ``r2_parameter``.

    Parameters
    ----------
    r2_parameter : float or None
        Measurement-noise factor of the parameter filter (> 0); None: ``r2``.

    """

    r2_parameter: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.r2_parameter is not None:
            object.__setattr__(
                self, "r2_parameter", check_positive("r2_parameter", self.r2_parameter)
            )


def _weights(settings: UKFSettings, n: int) -> Any:
    return sigma_weights(n, settings.sigma_points, settings.alpha, settings.beta, settings.kappa)


def _sigma_config(common: CommonArrays, weights: Any) -> np.ndarray:
    """The configuration vector of one unscented filter: spread, points, Euler substeps."""
    cfg = common.cfg.copy()
    cfg[pilot_core.CFG_SPREAD] = weights.spread
    cfg[pilot_core.CFG_COUNT] = weights.count
    cfg[pilot_core.CFG_SUBSTEPS] = pilot_core.euler_substeps(cfg[pilot_core.CFG_DT])
    return cfg


class _UnscentedPilotFilter(PilotFilter):
    """What the joint and the dual filter share: scratch, outputs, the smoother blocks."""

    # the C port of both filters' compiled path (_ukf_native.c), where it builds
    _native_binding = _ukf_native

    def _scratch(self, n: int) -> core.UKFScratch:
        internal = self._internal
        n_c = internal.n_states
        n_p = len(internal.parameter_names)
        return core.UKFScratch(
            work=unscented_work(n, 1),
            Q=np.zeros((n, n)),
            zero=np.zeros((n, n)),
            R=np.zeros((1, 1)),
            r=np.zeros(1),
            z_prev=np.zeros(n),
            cross=np.zeros((n, n)),
            point_p=np.zeros(n_p),
            f=np.zeros(n_c),
            F=np.zeros((n_c, n_c)),
            dfdp=np.zeros((n_c, n_p)),
            dgdx=np.zeros(n_c),
            dgdp=np.zeros(n_p),
            in_use=np.zeros(len(internal.input_names)),
            variance=np.zeros(n_p),
            scalars=np.zeros(3),
        )

    def _new_output(self, n: int, store: bool) -> core.UKFOutput:
        n_p = len(self._internal.parameter_names)
        size, second = self._sizes
        rows = n if store else 0
        return core.UKFOutput(
            **output_arrays(n, n_p),
            **trace_arrays(rows, size),
            cross=np.zeros((rows, size, size)),
            x_prior_2=np.zeros((rows, second)),
            P_prior_2=np.zeros((rows, second, second)),
            x_post_2=np.zeros((rows, second)),
            P_post_2=np.zeros((rows, second, second)),
        )

    def _smoother_inputs(self, out: core.UKFOutput) -> Any:
        """Random-walk blocks over the parameters' marginals (see the module docstring)."""

        def marginal(x_post, P_post, x_prior, P_prior, names):
            index = np.arange(len(names))
            square = np.ix_(np.arange(len(x_post)), index, index)
            return SmootherBlock(
                kind="random-walk",
                x_filtered=x_post[:, index],
                P_filtered=P_post[square],
                x_predicted=x_prior[:, index],
                P_predicted=P_prior[square],
                link=None,
                parameters={name: i for i, name in enumerate(names)},
            )

        first, second = self._blocks
        blocks = []
        if first:
            blocks.append(marginal(out.x_post, out.P_post, out.x_prior, out.P_prior, first))
        if second:
            blocks.append(
                marginal(out.x_post_2, out.P_post_2, out.x_prior_2, out.P_prior_2, second)
            )
        report = self._common.report
        return SmootherInputs.of_report(tuple(blocks), self._internal.parameter_names, report)

    def _config(
        self,
        cfg: np.ndarray,
        weights: Any,
        names: tuple[str, ...],
        n_states: int,
        n_moving: int,
        common: CommonArrays,
    ) -> core.UKFConfig:
        """Config of a filter whose first states are the parameters ``names``."""
        resolved = self.resolved
        model_names = self._internal.parameter_names
        slot = np.full(n_states, -1, dtype=np.int64)
        q = np.zeros(n_states)
        for i, name in enumerate(names):
            slot[i] = model_names.index(name)
            q[i] = resolved.Q[name]
        return core.UKFConfig(
            cfg=cfg,
            wm=weights.mean,
            wc=weights.cov,
            q=q,
            slot=slot,
            limit=slot.copy(),
            estimated=common.estimated,
            n_param=len(names),
            n_moving=n_moving,
        )

    def _prior(self, names: tuple[str, ...], n_states: int, common: CommonArrays) -> tuple:
        """Initial mean and covariance of a filter whose first states are ``names``."""
        resolved = self.resolved
        model_names = self._internal.parameter_names
        z = np.zeros(n_states)
        P = np.zeros((n_states, n_states))
        for i, name in enumerate(names):
            z[i] = common.p[model_names.index(name)]
            P[i, i] = resolved.P0[name]
        for i in range(len(names), n_states):
            P[i, i] = self._settings.noise.P0_canonical
        return z, P


class JointUKF(_UnscentedPilotFilter):
    """Joint unscented Kalman filter: pilot states and parameters in one filter.

    Parameters
    ----------
    settings
        A :class:`UKFSettings`; keyword arguments replace its fields (or build one).

    Examples
    --------
    >>> from manualcontrol.pilots import Pilot, simulate
    >>> recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", seed=0)
    >>> result = JointUKF(model="precision").estimate(recording)
    >>> round(result.final()["K_p"], 1)
    1.5

    """

    name = "joint-ukf"
    settings_type = UKFSettings
    _step_kernel = LazyKernel(_KERNEL_MODULE, "joint_step")
    _step_many_kernel = LazyKernel(_KERNEL_MODULE, "joint_step_many")

    def _start(self, resolved: ResolvedSettings, common: CommonArrays) -> None:
        internal = self._internal
        names = (*resolved.theta, *resolved.gains)
        n = len(names) + internal.n_states
        weights = _weights(self._settings, n)
        config = self._config(
            _sigma_config(common, weights), weights, names, n, len(resolved.theta), common
        )
        z, P = self._prior(names, n, common)
        belief = core.UKFBelief(
            z=z, P=P, prev_in=np.zeros(len(internal.input_names)), p=common.p, sc=common.sc
        )
        model = internal.kernel(())
        scratch = self._scratch(n)
        self._records = (model, config, belief, common.monitor, common.report, scratch)
        self._sizes = (n, 0)
        self._blocks = (names, ())


class DualUKF(_UnscentedPilotFilter):
    """Dual unscented Kalman filter: a state filter and a parameter filter side by side.

    Parameters
    ----------
    settings
        A :class:`DualUKFSettings`; keyword arguments replace its fields (or build one).

    """

    name = "dual-ukf"
    settings_type = DualUKFSettings
    _step_kernel = LazyKernel(_KERNEL_MODULE, "dual_step")
    _step_many_kernel = LazyKernel(_KERNEL_MODULE, "dual_step_many")

    def _start(self, resolved: ResolvedSettings, common: CommonArrays) -> None:
        internal = self._internal
        gains, theta = resolved.gains, resolved.theta
        n = len(gains) + internal.n_states
        n_t = len(theta)
        weights = _weights(self._settings, n)
        config = self._config(_sigma_config(common, weights), weights, gains, n, 0, common)
        s, P = self._prior(gains, n, common)
        belief = core.UKFBelief(
            z=s, P=P, prev_in=np.zeros(len(internal.input_names)), p=common.p, sc=common.sc
        )
        theta_weights = _weights(self._settings, max(n_t, 1))  # unused when n_t = 0
        theta_config = self._config(
            _sigma_config(common, theta_weights), theta_weights, theta, n_t, n_t, common
        )
        th, Pp = self._prior(theta, n_t, common)
        n_p = len(internal.parameter_names)
        theta_half = core.DualTheta(
            config=theta_config,
            th=th,
            Pp=Pp,
            work=unscented_work(n_t, 1),
            R=np.zeros((1, 1)),
            D=np.zeros((n, n_t)),
            M=np.zeros((n, n_t)),
            E=np.zeros((n_t, n_t)),
            zero=np.zeros((n_t, n_t)),
            point_s=np.zeros(n),
            point_x=np.zeros(internal.n_states),
            point_p=np.zeros(n_p),
        )
        model = internal.kernel(())
        scratch = self._scratch(n)
        self._records = (model, config, belief, common.monitor, common.report, scratch, theta_half)
        self._sizes = (n, n_t)
        self._blocks = (gains, theta)
