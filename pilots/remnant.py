"""Remnant models: coloured noise added to the pilot's control loop.

A remnant is a linear filter driven by unit Gaussian white noise: one standard normal
sample per simulation step, held over the step (so its level depends on ``dt``; the
gain ``K_r`` is calibrated to a power ratio in any case). Where the noise enters the
loop is the ``injection`` point:

``"output"``
    added to the pilot's control output, ``u = u_model + n`` (Schiess & Roland's
    stick ``delta = u + eta``; Zaal et al.).
``"input"``
    added to what the pilot perceives before the delay: the error ``e + n`` in a
    compensatory task (Popovici et al. 2017: "injected into the error signal"), the
    internal error ``e* + n`` in a preview task.
``"feedback"``
    added to the perceived controlled-element output, ``y + n`` (thesis Part I
    Sec. II-B: "located in the feedback loop of system output y").

``P_r`` requests a remnant power ratio ``var(u_n)/var(u)`` (thesis eq. 6), where
``u_n`` is the part of ``u`` caused by the remnant; :func:`~manualcontrol.pilots.simulate`
then calibrates ``K_r``. ``noise_variance`` instead gives the level as the variance ``q``
of the white driving noise itself (Schiess & Roland 1975: "the variance of the process
noise", their cases 59,600, 576 and 25 V^2/s^4): each held sample is ``N(0, q)``, so
``K_r = sqrt(q)``, the equivalent continuous intensity is ``q dt``, and the remnant's
level does not depend on the loop (their printed power ratios, 0.5, 0.04 and < 0.01,
cannot be reproduced from their q: with the loop's resonance the ratio of remnant to
stick power is about a quarter for every q, 0.24-0.25 over 60 s at 100 Hz).
"""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_positive, check_range

__all__ = [
    "INJECTION_POINTS",
    "LevisonRemnant",
    "Remnant",
    "SchiessRolandRemnant",
    "ZaalRemnant",
    "make_remnant",
]

FloatArray = NDArray[np.float64]

#: Where a remnant can enter the loop (see the module docstring).
INJECTION_POINTS: tuple[str, ...] = ("output", "input", "feedback")


@dataclass(frozen=True)
class Remnant(abc.ABC):
    """Base class: ``K_r`` times a filter shape, injected at ``injection``.

    ``P_r`` (optional, in (0, 1)) is the requested power ratio; when given, simulation
    replaces ``K_r`` by a calibrated gain. ``noise_variance`` (optional, >= 0) is the
    variance ``q`` of each held sample of the driving noise; when given it sets
    ``K_r = sqrt(q)`` (module docstring). The two are exclusive.
    """

    kind: ClassVar[str]
    K_r: float = 1.0
    injection: str = "output"
    P_r: float | None = None
    noise_variance: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "K_r", check_positive("K_r", self.K_r, allow_zero=True))
        check_choice("injection", self.injection, INJECTION_POINTS)
        if self.P_r is not None:
            object.__setattr__(
                self,
                "P_r",
                check_range("P_r", self.P_r, 0.0, 1.0, low_inclusive=False, high_inclusive=False),
            )
        if self.noise_variance is not None:
            if self.P_r is not None:
                raise ValueError(
                    f"give either P_r (a power ratio to calibrate K_r to) or noise_variance "
                    f"(K_r = sqrt(q)), not both; got P_r={self.P_r!r}, "
                    f"noise_variance={self.noise_variance!r}"
                )
            q = check_positive("noise_variance", self.noise_variance, allow_zero=True)
            object.__setattr__(self, "noise_variance", q)
            object.__setattr__(self, "K_r", math.sqrt(q))

    @abc.abstractmethod
    def shape(self) -> tuple[FloatArray, FloatArray]:
        """Filter numerator and denominator without the gain ``K_r``."""

    def filter(self) -> tuple[FloatArray, FloatArray]:
        """Remnant filter ``K_r * shape`` (descending powers of ``s``)."""
        num, den = self.shape()
        return self.K_r * num, den

    def with_gain(self, K_r: float) -> Remnant:
        """Copy with another gain (a different gain drops ``noise_variance``)."""
        if self.noise_variance is not None and K_r != self.K_r:
            return dataclasses.replace(self, K_r=K_r, noise_variance=None)
        return dataclasses.replace(self, K_r=K_r)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :func:`make_remnant` inverts it."""
        return {"kind": self.kind, **dataclasses.asdict(self)}

    def describe(self) -> str:
        """Short form for plots and logs."""
        shape = ", ".join(
            f"{f.name}={getattr(self, f.name):g}"
            for f in dataclasses.fields(self)
            if f.name not in ("K_r", "injection", "P_r", "noise_variance")
        )
        ratio = "" if self.P_r is None else f", P_r={self.P_r:g}"
        if self.noise_variance is not None:
            ratio += f", q={self.noise_variance:g}"
        return f"{type(self).__name__}(K_r={self.K_r:.4g}, {shape}, at {self.injection}{ratio})"


@dataclass(frozen=True)
class LevisonRemnant(Remnant):
    """Levison's first-order remnant ``K_r/(s + omega_r)`` (thesis eq. 5).

    Defaults follow Popovici et al. (2017, Sec. IV-A): break frequency 3 rad/s,
    injected at the error. The thesis's preview simulations use ``omega_r`` 10 rad/s
    (SI) and 0.01 rad/s (DI) at the ``y`` feedback (Part I Sec. IV-D); see
    :func:`make_remnant` presets.
    """

    kind: ClassVar[str] = "levison"
    injection: str = "input"
    omega_r: float = 3.0

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "omega_r", check_positive("omega_r", self.omega_r))

    def shape(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return np.array([1.0]), np.array([1.0, self.omega_r])


@dataclass(frozen=True)
class SchiessRolandRemnant(Remnant):
    """Schiess & Roland (1975) eq. 2: ``K_r/(s^2 + alpha_1 s + alpha_2)`` at the stick.

    Defaults are their simulated values alpha_1 = 4.427, alpha_2 = 10 (Table I).
    """

    kind: ClassVar[str] = "schiess-roland"
    alpha_1: float = 4.427
    alpha_2: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "alpha_1", check_positive("alpha_1", self.alpha_1))
        object.__setattr__(self, "alpha_2", check_positive("alpha_2", self.alpha_2))

    def shape(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return np.array([1.0]), np.array([1.0, self.alpha_1, self.alpha_2])


@dataclass(frozen=True)
class ZaalRemnant(Remnant):
    """Third-order remnant of Zaal et al. (2009), thesis eq. 2.4.

    ``K_r omega_r^3 / ((s^2 + 2 zeta_r omega_r s + omega_r^2)(s + omega_r))``. The
    default break frequency and damping (12.7 rad/s, 0.26) are typical values of that
    line of work; our references do not list them, so set them for your case.
    """

    kind: ClassVar[str] = "zaal"
    omega_r: float = 12.7
    zeta_r: float = 0.26

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "omega_r", check_positive("omega_r", self.omega_r))
        object.__setattr__(self, "zeta_r", check_positive("zeta_r", self.zeta_r))

    def shape(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        w, z = self.omega_r, self.zeta_r
        den = np.polymul([1.0, 2.0 * z * w, w * w], [1.0, w])
        return np.array([w**3]), den


_KINDS: dict[str, type[Remnant]] = {
    cls.kind: cls for cls in (LevisonRemnant, SchiessRolandRemnant, ZaalRemnant)
}


def _presets() -> dict[str, Remnant]:
    return {
        "popovici2017": LevisonRemnant(omega_r=3.0, injection="input", P_r=0.30),
        "vertregt2020-SI": LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.35),
        "vertregt2020-DI": LevisonRemnant(omega_r=0.01, injection="feedback", P_r=0.55),
        "schiess-roland1975": SchiessRolandRemnant(injection="output", P_r=0.5),
    }


#: Preset names accepted by :func:`make_remnant`.
REMNANT_PRESETS: tuple[str, ...] = tuple(_presets())


def make_remnant(spec: str | Remnant | Mapping[str, Any] | None) -> Remnant | None:
    """Return a remnant from a preset name, a remnant, a saved dict, or None.

    Presets carry each paper's filter, injection point and power ratio:
    ``"popovici2017"`` (Levison, 3 rad/s, at the error, 30 %), ``"vertregt2020-SI"``
    (10 rad/s, at the y feedback, 35 %), ``"vertregt2020-DI"`` (0.01 rad/s, 55 %),
    ``"schiess-roland1975"`` (second order at the stick, 50 %: their ratio of mean
    squared remnant to stick motion "about 0.5").
    """
    if spec is None or isinstance(spec, Remnant):
        return spec
    if isinstance(spec, str):
        check_choice("remnant", spec, REMNANT_PRESETS)
        return _presets()[spec]
    if isinstance(spec, Mapping):
        data = dict(spec)
        kind = check_choice("remnant kind", data.pop("kind", None), _KINDS)
        cls = _KINDS[kind]
        allowed = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise TypeError(
                f"{cls.__name__} got unknown field(s) {unknown}; allowed: {sorted(allowed)}"
            )
        return cls(**data)
    raise TypeError(f"remnant must be a preset name, a Remnant, a dict or None, got {spec!r}")
