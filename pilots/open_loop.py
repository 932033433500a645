"""Open-loop simulation of a delayed ARMAX system: Boer & Kenyon's (1998) Sec. IV.

Not every identification experiment is a pilot in a tracking loop. Boer & Kenyon test
their recursive delay identifier on a first-order ARMA system with a time-varying
delay, driven directly by a band-limited input (Sec. IV-A)::

    y_n = (b_0 + b_1 q^-1 + ..) q^-d_n / (1 - a_1 q^-1 - ..) r_n + v_n

:class:`ARMAXSystem` describes such a system (``q^-1`` a shift of ``step`` seconds,
the delay ``d`` in seconds as a number or a schedule, output noise ``v``) and
:func:`simulate_open_loop` runs it the paper's way: at ``simulation_rate`` (600 Hz) the
delay is a whole number of simulation samples (so it is fractional at the recording
rate), the ARMA recursion runs on every simulation sample with the ``step``-long shift
(each of the ``step * simulation_rate`` interleaved phases is the ARMA system at its own
rate), band-limited noise is added to the output, and the result is sampled at ``dt``
(60 Hz). The recorded input is ``ft`` and the output ``u`` (the signal names of a
pilot's input and response, which this system stands in for; the paper's ``r`` and
``y``), with ``u_n``, the noise part of ``u``, and the true parameter traces ``d``
(the delay applied, s), ``a_1 ..``, ``b_0 ..``, the names the
:class:`~manualcontrol.estimators.members.rdi.RDI` reports.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import (
    check_positive,
    check_vector,
    reject_unknown,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.schedules import Schedule, as_schedule
from manualcontrol.envs.signals import ForcingPair, band_limited_noise, forcing_preset
from manualcontrol.pilots._random import as_generator

__all__ = ["ARMAXSystem", "simulate_open_loop"]

FloatArray = NDArray[np.float64]

#: Whole-number tolerance of the ratios of the rates (``step`` and ``dt`` in samples).
_RATIO_TOLERANCE = 1e-9


def _whole(name: str, value: float) -> int:
    count = round(value)
    if count < 1 or abs(value - count) > _RATIO_TOLERANCE * max(1.0, value):
        raise ValueError(f"{name} must be a whole number of simulation samples, got {value!r}")
    return count


@dataclass(frozen=True)
class ARMAXSystem:
    """A delayed ARMAX system ``(b_0 + b_1 q^-1 + ..) q^-d / (1 - a_1 q^-1 - ..)``.

    Parameters
    ----------
    a
        AR coefficients ``a_1 ..`` (may be empty).
    b
        MA coefficients ``b_0 ..`` on the delayed input (at least one).
    delay
        ``d`` in seconds: a number or a :class:`~manualcontrol.envs.schedules.Schedule`
        (e.g. a :class:`~manualcontrol.envs.schedules.BandLimitedRandomWalk`).
    step
        The shift ``q^-1`` in seconds (the rate the coefficients belong to), > 0.
    noise_std, noise_cutoff_hz
        Standard deviation (>= 0; 0: noise free) and cut-off (Hz) of the band-limited
        output noise ``v``.
    simulation_rate
        Samples per second of the simulation (> 0); ``step`` must be a whole number of
        its samples.

    """

    a: tuple[float, ...]
    b: tuple[float, ...]
    delay: float | Schedule
    step: float = 1.0 / 15.0
    noise_std: float = 0.0
    noise_cutoff_hz: float = 3.0
    simulation_rate: float = 600.0

    def __post_init__(self) -> None:
        a = tuple(float(v) for v in check_vector("a", list(self.a)))
        b = tuple(float(v) for v in check_vector("b", list(self.b), min_length=1))
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        try:
            object.__setattr__(self, "delay", as_schedule(self.delay))
        except (TypeError, ValueError) as error:
            raise type(error)(f"delay: {error}") from None
        object.__setattr__(self, "step", check_positive("step", self.step))
        object.__setattr__(
            self, "noise_std", check_positive("noise_std", self.noise_std, allow_zero=True)
        )
        object.__setattr__(
            self, "noise_cutoff_hz", check_positive("noise_cutoff_hz", self.noise_cutoff_hz)
        )
        object.__setattr__(
            self, "simulation_rate", check_positive("simulation_rate", self.simulation_rate)
        )
        _whole("step", self.step * self.simulation_rate)
        if self.noise_cutoff_hz > 0.5 * self.simulation_rate:
            raise ValueError(
                f"noise_cutoff_hz must not exceed the Nyquist frequency "
                f"{0.5 * self.simulation_rate:g} Hz, got {self.noise_cutoff_hz!r}"
            )

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``("d", "a_1", .., "b_0", ..)``, the RDI's symbols."""
        return (
            "d",
            *(f"a_{i}" for i in range(1, len(self.a) + 1)),
            *(f"b_{m}" for m in range(len(self.b))),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` inverts it."""
        return {
            "a": list(self.a),
            "b": list(self.b),
            "delay": self.delay.to_dict(),
            "step": self.step,
            "noise_std": self.noise_std,
            "noise_cutoff_hz": self.noise_cutoff_hz,
            "simulation_rate": self.simulation_rate,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ARMAXSystem:
        """Inverse of :meth:`to_dict` (also a suite file's ``[batch.system]`` table)."""
        if not isinstance(data, Mapping):
            raise TypeError(f"an ARMAX system must be a table, got {data!r}")
        items = dict(data)
        reject_unknown(
            "ARMAXSystem",
            items,
            ("a", "b", "delay", "step", "noise_std", "noise_cutoff_hz", "simulation_rate"),
        )
        missing = [key for key in ("a", "b", "delay") if key not in items]
        if missing:
            raise TypeError(f"ARMAXSystem is missing key(s) {', '.join(missing)}")
        items["delay"] = Schedule.from_dict(items["delay"])
        return cls(**items)


def simulate_open_loop(
    system: ARMAXSystem,
    forcing: str | ForcingPair = "boer-kenyon1998",
    *,
    realisation: int = 0,
    dt: float = 1.0 / 60.0,
    run_in: float = 10.0,
    measurement_time: float = 60.0,
    seed: int | np.random.Generator | None = None,
    keep_run_in: bool = False,
) -> Recording:
    """Simulate ``system`` driven by the target of ``forcing``; see the module docstring.

    Parameters
    ----------
    system
        The delayed ARMAX system.
    forcing, realisation
        Forcing preset name and realisation, or a ForcingPair; its target is the input.
    dt
        Sample time of the recording (s); a whole number of simulation samples.
    run_in, measurement_time
        Simulated before ``t = 0`` (from rest, cut unless ``keep_run_in``) and after (s).
    seed
        Seed or generator of the output noise (the only random input).
    keep_run_in
        Keep the run-in in the recording (times from ``-run_in``).

    """
    if not isinstance(system, ARMAXSystem):
        raise TypeError(f"system must be an ARMAXSystem, got {system!r}")
    if isinstance(forcing, str):
        forcing = forcing_preset(forcing, realisation)
    elif not isinstance(forcing, ForcingPair):
        raise TypeError(f"forcing must be a preset name or a ForcingPair, got {forcing!r}")
    if forcing.target is None:
        raise ValueError(f"forcing {forcing.name!r} has no target to drive the system with")
    dt = check_positive("dt", dt)
    run_in = check_positive("run_in", run_in, allow_zero=True)
    measurement_time = check_positive("measurement_time", measurement_time)
    rate = system.simulation_rate
    h = 1.0 / rate
    decimation = _whole("dt", dt * rate)
    lag = _whole("step", system.step * rate)
    rng, seed_used = as_generator(seed)
    n_run_in = round(run_in / dt)
    n = n_run_in + round(measurement_time / dt)
    n_fine = n * decimation
    t_fine = (np.arange(n_fine) - n_run_in * decimation) * h
    delay = np.asarray(system.delay(t_fine), dtype=np.float64)
    if not np.all(np.isfinite(delay)):
        raise ValueError("the delay schedule gave non-finite values")
    shifts = np.rint(delay * rate).astype(np.int64)
    # the input from the earliest sample any delayed read needs to the latest
    earliest = min(0, int((np.arange(n_fine) - (len(system.b) - 1) * lag - shifts).min()))
    latest = max(n_fine - 1, int((np.arange(n_fine) - shifts).max()))
    offset = -earliest
    r_times = t_fine[0] + np.arange(earliest, latest + 1) * h
    r = np.asarray(forcing.target(r_times), dtype=np.float64)
    clean = np.zeros(n_fine)
    # imported here: the bench reads this module's system for its suites, and needs
    # numba only where an open-loop run is simulated
    from manualcontrol.pilots._open_loop_kernels import armax

    armax(
        np.asarray(system.a, dtype=np.float64),
        np.asarray(system.b, dtype=np.float64),
        r,
        offset,
        shifts,
        lag,
        clean,
    )
    noise = (
        band_limited_noise(n_fine, h, system.noise_cutoff_hz, system.noise_std, rng)
        if system.noise_std > 0.0
        else np.zeros(n_fine)
    )
    pick = slice(0, n_fine, decimation)
    part = slice(0, n) if keep_run_in else slice(n_run_in, n)
    t = ((np.arange(n) - n_run_in) * dt)[part]
    parameters = {"d": (shifts[pick] * h)[part]}
    for i, value in enumerate(system.a, start=1):
        parameters[f"a_{i}"] = np.full(t.shape, value)
    for m, value in enumerate(system.b):
        parameters[f"b_{m}"] = np.full(t.shape, value)
    return Recording(
        signals={
            "t": t,
            "ft": r[offset : offset + n_fine][pick][part],
            "u": (clean + noise)[pick][part],
            "u_n": noise[pick][part],
        },
        dt=dt,
        parameters=parameters,
        metadata={
            "task": "open-loop",
            "system": system.to_dict(),
            "forcing": forcing.to_dict(),
            "forcing_name": forcing.name,
            "realisation": forcing.realisation,
            "dt": dt,
            "run_in": run_in,
            "measurement_time": measurement_time,
            "seed": seed_used,
            "source": "manualcontrol.pilots.open_loop.simulate_open_loop",
        },
    )
