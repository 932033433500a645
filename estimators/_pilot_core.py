"""Compiled pieces every filter on a pilot internal model shares (DEKF, joint and dual UKF).

Each sample of such a filter starts the same way (the windowed signal variances that set
``R = r^2 var(u)`` and the chain-input process noise ``q^2 var(e)``, Popovici eqs.
24-25 and thesis eqs. 29-30; dropped inputs held at their last value) and ends the same
way (every parameter's mean and standard deviation reported in model order, limits and
pins tracked, divergence recorded; a diverged filter stops and repeats its last
estimate). The filters differ only in between: how the belief is predicted and
corrected.

The records are namedtuples of arrays:

* ``cfg``: the ``CFG_*`` configuration vector;
* ``sc``: the ``SC_*`` scalar state (sample counter, first-window variances, window
  sums, frozen flag, divergence record);
* :data:`PilotMonitor`: the variance windows, pin counters and last reported values;
* :data:`PilotReport`: how parameters are reported (limits, the report transform
  ``offset + sign value`` that turns ``tau_f*`` back into ``tau_f``);
* :data:`PilotOutput`: one row per sample of means, standard deviations, the primary
  output's (prediction, innovation, variance), flags and pins.

Sample rates: the papers ran at 100 Hz (:data:`PAPERS_DT`), and two of their choices are
steps of that rate, not of the pilot: the Euler prediction of the canonical states
(Popovici eq. 8, thesis eq. 13), whose error grows with its step ``h`` (it damps the
neuromuscular mode less than the pilot does, and ``zeta_nms`` comes out about
``omega_nms h / 2`` high), and eq. 49 as printed (the DEKF's total derivative, weighted
by 1/dt at 100 Hz). :func:`euler_substeps` keeps the Euler step at most the papers'
0.01 s at every rate (one step a sample at 100 Hz and faster, two at 50 and 60 Hz), and
the DEKF keeps the printed weight at 1/(0.01 s). Everything else the DEKF and the
unscented filters read is in seconds (the 5-s variance window, the pin time) or keeps
its meaning per second by itself: with ``Gamma = I dt`` a random walk's variance a
sample is ``Q dt^2`` and ``R`` is a sample's variance, so a filter's time constant,
about ``dt sqrt(R / (Q dt^2)) = sqrt(R/Q)`` seconds, is the same at every rate. (The RML,
whose remnant state has an exact, continuous noise, takes ``R`` and ``Q`` per second
instead: :mod:`~manualcontrol.estimators.members.rml`, "Sample rates".)

The kernels live in :mod:`~manualcontrol.estimators._pilot_kernels`, imported on first
use (a process whose filters run in C never imports numba); the record layouts and
constants they and the C ports read stay here.
"""

from __future__ import annotations

import math
from collections import namedtuple

from manualcontrol.envs._lazy import kernels_on_first_use

# numba kernels read this module's constants
# ---- indices into the configuration vector ``cfg``
CFG_DT = 0
CFG_Q2 = 1
CFG_R2 = 2
CFG_WINDOW = 3  # samples N; the window holds N + 1 samples
CFG_FIRST_WINDOW = 4  # 1: use var0 for k < N (papers); 0: causal growing window
CFG_FLOOR = 5
CFG_JITTER = 6
CFG_MAX_COV = 7
CFG_DIMENSIONAL = 8  # DEKF: 1 = eq. 49 with dt on df/dtheta; 0 = as printed
CFG_FIXED_R = 9  # > 0 replaces r^2 var(u)
CFG_FIXED_QE = 10  # > 0 replaces q^2 var(e)
CFG_ERROR_STATE = 11
CFG_GAMMA2 = 12  # Gamma^2: dt^2 (Euler noise input) or 1 (identity)
CFG_R2_PARAMETER = 13  # r^2 of a parameter filter (the same as CFG_R2 unless set)
CFG_SPREAD = 14  # unscented filters: sigma-point spread c
CFG_COUNT = 15  # unscented filters: sigma points to propagate (2N or 2N + 1)
CFG_SUBSTEPS = 16  # Euler substeps a sample (euler_substeps; 0 reads as 1)
CFG_SIZE = 17

#: The papers' sample time (s): Popovici et al. (2017) and the thesis ran at 100 Hz, the
#: step of their Euler prediction and of eq. 49 as printed (module docstring).
PAPERS_DT = 0.01

# ---- indices into the scalar vector ``sc``
SC_K = 0
SC_VAR_U0 = 1
SC_VAR_E0 = 2
SC_U = 3  # shift, sum, sum of squares, count
SC_E = 7
SC_FROZEN = 11
SC_DIV_INDEX = 12
SC_DIV_REASON = 13
SC_DIV_PARAM = 14
SC_SIZE = 15


def euler_substeps(dt: float, per_papers_step: int = 1) -> int:
    """Euler substeps over a sample of ``dt`` s: ``per_papers_step`` per :data:`PAPERS_DT`.

    ``ceil(per_papers_step dt / 0.01 s)``, at least 1: no substep is longer than
    ``0.01 s / per_papers_step``, the step the papers' rate gives (module docstring). With
    the default one a sample at 100 Hz and faster, two at 50 and 60 Hz; a relative
    tolerance of 1e-9 keeps a ``dt`` that rounding put a hair above 0.01 s at one.
    """
    return max(1, math.ceil(per_papers_step * dt / PAPERS_DT * (1.0 - 1e-9)))


PilotMonitor = namedtuple(
    "PilotMonitor", ["buf_u", "buf_e", "pins", "pin_ring", "last_mean", "last_std", "pinned_now"]
)
PilotReport = namedtuple("PilotReport", ["lo", "hi", "offset", "sign"])
PilotOutput = namedtuple("PilotOutput", ["mean", "std", "scalar", "flag", "pinned"])


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "noise_levels",
    "inputs_in_use",
    "report_frozen",
    "report_row",
    "REASON_COVARIANCE",
    "REASON_NONE",
    "REASON_NONFINITE",
    "REASON_PINNED",
    "track_pins",
    "window_push",
    "window_variance",
)
__getattr__ = kernels_on_first_use(globals(), "manualcontrol.estimators._pilot_kernels", _KERNELS)
