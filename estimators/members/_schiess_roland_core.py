"""Compiled core of the Schiess-Roland joint EKF: one step, and a whole run.

The filter of :mod:`~manualcontrol.estimators.members.schiess_roland` on small records
(namedtuples of arrays): :func:`sr_step` advances an :data:`SRBelief`
by one sample and writes that sample's estimate into row ``row`` of an
:data:`SROutput`; :func:`sr_run` loops it over a recording. ``update`` and
``estimate`` both call :func:`sr_step`, so they give identical numbers. The covariance
algebra (Joseph correction with the m = 2 Cholesky solve, symmetrisation, health,
pins, reporting) is the family's shared code.

State (eqs. 6, 14): ``x = (c, c', u, y_4, eta, eta', K_1, tau_1, tau_2, tau_3, theta,
alpha_1, alpha_2)``. Over a step the first six follow the linear system of eqs. 7-12,

    z' = A(p) z + b(p) e_d(t) + e_6 w,

with the parameters ``p`` frozen (eq. 14) and the delayed error
``e_d(t) = D(t - theta) - c(t - theta)`` read from the history of the forcing and of
the filtered plant output (eq. 17). Eq. 18 is integrated exactly for a delayed input
held over the step (``hold``, the paper) or ramped between its values at the two ends
of the step (``ramp``): the exact flow of the augmented linear system is summed as a
Taylor series of its matrix exponential, and the same recursion differentiated gives
the transition Jacobian ``Phi`` (eq. 19) with respect to the states, the parameters in
``A`` and ``b``, and the delayed input. The delay enters through the input only:
``d e_d / d theta = -de/dt (t - theta)`` (the chain rule on the delayed error; the
paper gives no ``df/dtheta``), with ``de/dt = dD/dt - c'`` from the forcing history
and the filtered ``c'``. The remnant's white input ``w`` is held over each sample like
the simulation's, so its exact discrete covariance is ``q G_w G_w^T`` with
``G_w = int_0^dt e^(A s) e_6 ds``.

The kernels live in :mod:`~manualcontrol.estimators.members._schiess_roland_kernels`,
imported on first use (where the C port runs, the filter never imports numba); the
records, their builder and the constants the kernels read stay here.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.estimators._pilot_core import SC_FROZEN, SC_K  # noqa: F401
from manualcontrol.estimators.filters.kalman import kalman_work

# numba kernels read this module's constants
# ---- layout of the state vector (eqs. 6 and 14)
N_DYNAMIC = 6
N_PARAMETERS = 7
N_STATES = N_DYNAMIC + N_PARAMETERS
I_C, I_C_RATE, I_U, I_Y4, I_ETA, I_ETA_RATE = range(N_DYNAMIC)
I_K1, I_TAU1, I_TAU2, I_TAU3, I_THETA, I_ALPHA1, I_ALPHA2 = range(N_DYNAMIC, N_STATES)

# ---- configuration vector ``cfg``
CFG_DT = 0
CFG_PLANT_GAIN = 1
CFG_PROCESS_NOISE = 2
CFG_JITTER = 3
CFG_MAX_COV = 4
CFG_BICUBIC = 5  # 1: fractional (bicubic) read of the delayed signals, 0: q = round(theta/dt)
CFG_RAMP = 6  # 1: delayed input linear over the step, 0: held (eq. 18)
CFG_ADAPTIVE = 7  # 0 off, 1 full (A1-A6), 2 modified (plant output only)
CFG_MAX_DELAY = 8
CFG_NOISE_FORM = 9  # 0: held white input (q G_w G_w^T), 1: q on eta' per sample (the paper)
CFG_SIZE = 10

ADAPTIVE_OFF = 0
ADAPTIVE_FULL = 1
ADAPTIVE_MODIFIED = 2

#: Largest ``||A dt||`` summed in one Taylor series; longer steps are split.
_SERIES_REACH = 4.0
_SERIES_TOLERANCE = 1e-17  # relative to the largest state entry (or 1)
_SERIES_TERMS = 60
#: Most substeps a sample's flow is split into. Past it ``||A dt|| > 4096``: at 100 Hz
#: a mode near 400,000 rad/s (``tau_1`` under about 1/4000 of the sample, ``tau_2``
#: under 1/2000, a pole gone through zero), which no pilot's parameters come near and
#: no sampled record can show. A belief that gets there has diverged, and the filter
#: stops at that sample (``REASON_BEYOND_SAMPLE_RATE``): splitting on, up to 2^20
#: substeps, cost up to a second of arithmetic a sample before its values turned
#: non-finite a few samples later.
_FLOW_SPLIT_CAP = 1 << 10

#: Settings as arrays: ``cfg`` (``CFG_*``), the adaptive noise-input vector ``gamma``
#: (13,), the limit entry of each state (-1: none), the estimated parameters (7,) and the
#: measurement noise variances ``R`` (2, 2) of (stick, plant output).
SRConfig = namedtuple("SRConfig", ["cfg", "gamma", "state_limit", "estimated", "R"])
#: The belief ``x, P``; the scalar state ``sc`` (``SC_*`` of ``_pilot_core``); the
#: histories (rings) of the forcing ``D``, the filtered ``c`` and ``c'``; the adaptive
#: noise window ``q_window`` and ``q_sum`` = (sum, count, pushes); ``prev_d``/``in_d`` the
#: forcing in use (a dropped one holds its last value).
SRBelief = namedtuple(
    "SRBelief",
    ["x", "P", "sc", "hist_d", "hist_c", "hist_rate", "q_window", "q_sum", "prev_d", "in_d"],
)
SRScratch = namedtuple(
    "SRScratch",
    [
        "terms",
        "next_terms",
        "sums",
        "Z",
        "J",
        "Jrho",
        "Gw",
        "z",
        "v",
        "T1",
        "U",
        "Pn",
        "H2",
        "R2",
        "r2",
        "H1",
        "R1",
        "r1",
        "work2",
        "work1",
        "p",
        "variance",
        "scalars",
    ],
)
#: Per-row outputs. ``scalar`` = (prediction, innovation, variance) of the stick (the
#: primary output); ``predictions``, ``innovations`` (n, 2) and ``S`` (n, 2, 2) of both;
#: ``states`` (n, 7) the six dynamic states and the adaptive noise in use; the smoother
#: storage (priors, posteriors, ``Phi``) has one row per sample or none.
SROutput = namedtuple(
    "SROutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "predictions",
        "innovations",
        "S",
        "states",
        "x_prior",
        "P_prior",
        "x_post",
        "P_post",
        "Phi",
    ],
)

# columns of the Taylor recursion: the state, Z = d z/d z0 (6), the parameters in A
# and b (6: K_1, tau_1, tau_2, tau_3, alpha_1, alpha_2), the input value, the input
# slope, the white noise input
COL_Z = 0
COL_PHI = 1
COL_PARAM = 7
COL_E0 = 13
COL_RHO = 14
COL_W = 15
N_COLUMNS = 16
#: State index of each parameter column (theta has none: it acts through the input).
_PARAM_STATE = (I_K1, I_TAU1, I_TAU2, I_TAU3, I_ALPHA1, I_ALPHA2)


def new_scratch() -> SRScratch:
    """Scratch arrays of one filter."""
    n = N_STATES
    return SRScratch(
        terms=np.zeros((N_COLUMNS, N_DYNAMIC)),
        next_terms=np.zeros((N_COLUMNS, N_DYNAMIC)),
        sums=np.zeros((N_COLUMNS, N_DYNAMIC)),
        Z=np.zeros((N_DYNAMIC, N_DYNAMIC)),
        J=np.zeros((N_DYNAMIC, N_PARAMETERS)),
        Jrho=np.zeros(N_DYNAMIC),
        Gw=np.zeros(N_DYNAMIC),
        z=np.zeros(N_DYNAMIC),
        v=np.zeros(2 * N_DYNAMIC),
        T1=np.zeros((N_DYNAMIC, N_PARAMETERS)),
        U=np.zeros((N_DYNAMIC, N_DYNAMIC)),
        Pn=np.zeros((n, n)),
        H2=np.zeros((2, n)),
        R2=np.zeros((2, 2)),
        r2=np.zeros(2),
        H1=np.zeros((1, n)),
        R1=np.zeros((1, 1)),
        r1=np.zeros(1),
        work2=kalman_work(n, 2),
        work1=kalman_work(n, 1),
        p=np.zeros(N_PARAMETERS),
        variance=np.zeros(N_PARAMETERS),
        scalars=np.zeros(3),
    )


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_apply_a",
    "input_gains",
    "_input_gain_derivatives",
    "_add_a_derivative",
    "_series_norm",
    "_substep",
    "flow",
    "predict_covariance_structured",
    "_ring",
    "_error_at",
    "delayed_error",
    "adaptive_variance",
    "_store_phi",
    "_stopped_row",
    "sr_step",
    "sr_run",
    "bicubic_derivative_weights",
    "bicubic_weights",
    "report_frozen",
    "report_row",
    "clamp",
    "joseph_correct",
    "symmetrise",
    "belief_health",
    "store_belief",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._schiess_roland_kernels", _KERNELS
)
