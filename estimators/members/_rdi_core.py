"""Compiled core of the recursive delay identifier (Boer & Kenyon 1998): one step, a run.

Pure numerics on small records (namedtuples of arrays), in the
manner of :mod:`~manualcontrol.estimators.members._dekf_core`: :func:`rdi_step` consumes one
sample (input ``r_k``, output ``y_k``) and writes that sample's estimate into row
``row`` of an :data:`RDIOutput`; :func:`rdi_run` loops it over a recording. The online
``RDI.update`` and the batch ``RDI.estimate`` both call :func:`rdi_step` on the same
ring buffers, so they give identical numbers. The covariance algebra is the family's
(:func:`~manualcontrol.estimators.filters.kalman.joseph_correct`, ``clamp``,
:func:`~manualcontrol.estimators.filters.monitor.belief_health`).

The model (Sec. III-A, III-D, with the delay as a positive lag ``d`` in seconds)::

    y_hat_k = sum_i a_i y[k - i lam] + sum_m b_m r(k - m lam - d/dt)

at the undecimated sample ``k`` (``dt``); ``lam`` is the decimation factor, so the
ARMAX shift is ``lam`` samples. ``r`` between samples comes from the bicubic kernel of
the Appendix (:func:`_read`). The filter state holds the estimated entries of
``theta = [d, a_1 .., a_na, b_0 .., b_nb]`` (known ones are removed from it, Sec. III-E);
the parameters are random walks (eqs. 1a, 2a with ``f`` the identity), so the time
update adds ``Q`` to ``P`` once per identification step, every ``lam`` samples
(Sec. III-D's decimation). The measurement Jacobian (eq. 2b, Sec. III-D)::

    dy_hat/dd   = -sum_m b_m r'(k - m lam - d/dt)   (r' per second)
    dy_hat/da_i = y[k - i lam]
    dy_hat/db_m = r(k - m lam - d/dt)

Sign constraints (Sec. III-F, ``cfg[CFG_SIGN]``): an identification step whose measured
``y_k`` or rate ``y_k - y_{k-1}`` has the opposite sign of the prediction's (``y_hat_k``,
``y_hat_k - y_hat_{k-1}`` at the same ``theta``) keeps its time update and skips the
correction. Samples between identification steps only report (the belief is held).

Storage for the smoother (one row per sample when the output has rows): the prior
(``P + Q`` at an identification step, the previous posterior otherwise) and the
posterior, so the random-walk RTS smoother over the rows is the smoother over the
identification steps, each held over its samples.

The kernels live in :mod:`~manualcontrol.estimators.members._rdi_kernels`, imported on
first use (where the C port runs, an RDI never imports numba); the records and the
constants the kernels read stay here.
"""

from __future__ import annotations

from collections import namedtuple
from typing import TYPE_CHECKING

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators.filters.monitor import (  # noqa: F401  (the RDI reads them here)
    REASON_COVARIANCE,
    REASON_NONE,
    REASON_NONFINITE,
)

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.members._rdi_kernels import (
        predict,
        rdi_run,
        rdi_step,
        simulate_output,
    )

# numba kernels read this module's constants
# ---- indices into the configuration vector ``cfg``
CFG_DT = 0
CFG_LAMBDA = 1  # decimation factor (samples per identification step)
CFG_R = 2  # measurement noise variance
CFG_SIGN = 3  # 1: sign constraints on; 0: off
CFG_JITTER = 4
CFG_MAX_COV = 5
CFG_NA = 6
CFG_NB = 7
CFG_SIZE = 8

# ---- indices into the scalar vector ``sc``
SC_K = 0  # samples consumed
SC_FROZEN = 1
SC_DIV_INDEX = 2
SC_DIV_REASON = 3
SC_STEPS = 4  # identification steps taken
SC_HELD = 5  # of which held by the sign constraints
SC_SIZE = 6

#: Settings as arrays: ``cfg`` (``CFG_*``), the process noise of each filter state, the
#: parameter each filter state holds, the limits of every parameter (``lo``, ``hi``;
#: infinite where there is none) and which filter states have limits (``limit``, the
#: parameter index or -1).
RDIConfig = namedtuple("RDIConfig", ["cfg", "q", "state_param", "limit", "lo", "hi"])
#: The belief: filter state ``x, P``, the whole parameter vector ``p`` (model order),
#: ring buffers of the input and output samples, and the scalars ``sc`` (``SC_*``).
RDIBelief = namedtuple("RDIBelief", ["x", "P", "p", "ring_r", "ring_y", "sc"])
#: Scratch: the Jacobian row ``H`` (1, n_s), ``R`` (1, 1), the innovation (1,), the
#: Kalman work record, per-parameter variances and gradient (n_p,), the row's flags (6,).
RDIScratch = namedtuple("RDIScratch", ["H", "R", "r", "work", "variance", "gradient", "flags"])
#: Per-row outputs (``scalar``: prediction, innovation, its variance; ``flag``: finite,
#: covariance ok, dropped, diverged, identified, held); the smoother storage has one row
#: per sample or none.
RDIOutput = namedtuple(
    "RDIOutput",
    ["mean", "std", "scalar", "flag", "pinned", "x_prior", "P_prior", "x_post", "P_post"],
)


__all__ = [
    "CFG_DT",
    "CFG_JITTER",
    "CFG_LAMBDA",
    "CFG_MAX_COV",
    "CFG_NA",
    "CFG_NB",
    "CFG_R",
    "CFG_SIGN",
    "CFG_SIZE",
    "REASON_NONE",
    "SC_DIV_INDEX",
    "SC_DIV_REASON",
    "SC_FROZEN",
    "SC_HELD",
    "SC_K",
    "SC_SIZE",
    "SC_STEPS",
    "RDIBelief",
    "RDIConfig",
    "RDIOutput",
    "RDIScratch",
    "predict",
    "rdi_run",
    "rdi_step",
    "simulate_output",
]


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_read",
    "_past_output",
    "predict",
    "_report",
    "rdi_step",
    "rdi_run",
    "simulate_output",
    "bicubic_derivative_weights",
    "bicubic_weights",
    "clamp",
    "joseph_correct",
    "belief_health",
    "store_belief",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._rdi_kernels", _KERNELS
)
