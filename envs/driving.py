"""Lane keeping: a bicycle-model car on a road of given curvature, steered by a driver.

The second task world beside tracking (Zhao et al. 2019, Sec. 5.1: "a bicycle model ...
with a fixed speed 64 km/h on a predefined road"). A driver (or an agent) turns the
steering wheel; the car should stay in its lane.

Vehicle
-------
Linear single-track ("bicycle") model at constant speed ``v_x`` in road coordinates,
small angles, per-tyre cornering stiffnesses ``c_f``, ``c_r`` (two tyres an axle, the
factor 2 of this line of work's equations)::

    alpha_f = delta_d/R_s - (v_y + l_f r)/v_x        alpha_r = -(v_y - l_r r)/v_x
    F_f = 2 c_f alpha_f                              F_r = 2 c_r alpha_r
    m (v_y' + v_x r) = F_f + F_r                     I_z r' = l_f F_f - l_r F_r
    psi_L' = r - v_x kappa(s)                        y_L' = v_y + v_x psi_L,   s = v_x t

``v_y`` lateral velocity, ``r`` yaw rate, ``psi_L`` heading relative to the road tangent,
``y_L`` lateral offset of the centre of gravity from the lane centre (positive to the
left), ``kappa(s)`` the road curvature at the car (positive for a left bend), ``delta_d``
the steering-wheel angle, ``R_s`` the steering ratio.

Steering (``steering=``)
    ``"torque"`` (default): the action is the driver's torque ``Gamma_d`` on the wheel,
    which turns through the steering column
    ``J_s delta_d'' = Gamma_d + Gamma_s - B_s delta_d' - K_s delta_d``. ``Gamma_s =
    -K_m eta_t F_f / R_s`` is the self-aligning torque felt at the wheel (pneumatic trail
    ``eta_t`` times the front axle force, through the steering ratio and the manual part
    ``K_m`` of the power-assisted column; negative for a left steer: it pulls the wheel
    back). ``K_s = k_s v_x`` is the column's speed-dependent stiffness: the cybernetic
    driver model holds an internal model of it, ``K_r v_x`` (Zhao eq. 2, Table 2: "internal
    gain of steering column stiffness"), so with ``k_s = 1`` N m s/rad per m/s the nominal
    driver's steady steering angle equals its intention (``delta_d = delta_sw``).
    ``"angle"``: the action is the steering-wheel angle ``delta_d`` itself (no column).

Vehicle parameters (:func:`vehicle_preset`, ``"mid-size"``, the published values for a
mid-size car of the issue: ``c_f`` 51,845 and ``c_r`` 54,610 N/rad, ``m`` 1,834.9 kg,
``I_z`` 2,800 kg m^2, ``l_f`` 1.249 m, ``l_r`` 1.56 m, ``R_s`` 14.5405, ``eta_t`` 0.245 m,
``K_m`` 0.031, ``mu`` 0.8). The column inertia ``J_s`` 0.05 kg m^2 and damping ``B_s``
0.8 N m s/rad are ours (the paper gives no column): of the order used in shared-steering
studies, with ``B_s`` chosen where the nominal driver's closed loop is best damped
(lateral mode damping ratio 0.21, 0.19 with both visual gains 40 % higher; 0.06 with the
often-quoted 5.73 N m s/rad). Width 1.8 m.

Road
----
A :class:`Road` is a sequence of segments (straights, clothoids, arcs) giving the
curvature along the path; presets (:data:`ROAD_PRESETS`) and seedable random roads
(:meth:`Road.random`). Beyond its end a road continues straight. The curvature is
sampled at the car's position every sample and held over the sample.

Observation (float64), the driver model's input vector ``u`` (Zhao eq. 2)
--------------------------------------------------------------------------

=====  ==============  =======  ===============================================================
index  name            unit     meaning
=====  ==============  =======  ===============================================================
0      ``theta_far``   rad      far-point angle ``far_gain * kappa(s + far_preview)``: the
                                anticipated curvature (default 15 m times the curvature 15 m
                                ahead, one published choice)
1      ``theta_near``  rad      near-point angle ``-e_near / near_distance``, ``e_near = y_L +
                                d psi_L - kappa(s) d^2/2`` the lateral error of the point
                                ``d`` = 5 m ahead (small angles)
2      ``delta_d``     rad      steering-wheel angle
3      ``Gamma_s``     N m      self-aligning torque at the wheel
=====  ==============  =======  ===============================================================

``include_rates=True`` appends the backward-difference rates of the four (zero on the
first observation), ``include_previous_action=True`` the previous action.

Action: ``Box(-action_bound, action_bound, (1,), float64)``: the torque (N m, default
bound 20) or the wheel angle (rad, default bound 2); held over each sample (zero-order
hold; the car is advanced by the exact discretisation of the model above). Actions
outside are clipped and counted. An action must be a real array-like of shape ``(1,)``
(as the action space says; a bare number, a string, a bool, a complex number or a
wrong shape raise ``TypeError``/``ValueError`` naming ``action``); non-finite actions
raise ``ValueError``.

Reward (``reward=``): ``"bounded"`` (default) ``1/(1 + (y_L/reward_scale)^2)`` in (0, 1],
positive so ending an episode early never pays; ``"squared_offset"``
``-(y_L/reward_scale)^2``; ``"squared_offset_and_effort"`` adds ``-effort_weight
(action/action_bound)^2``. ``reward_scale`` 0.25 m.

Loss of control (``loss_of_control=True``): the episode terminates when the car leaves
its lane, ``|y_L| > (lane_width - vehicle width)/2`` (0.85 m for a 3.5-m lane), or its
lateral acceleration exceeds the friction limit ``mu g`` (the linear tyres no longer
hold). Episodes start at rest on the lane centre (every state zero) and are truncated
after ``round((run_in + measurement_time)/dt)`` steps; the measurement time defaults to
the time the road takes. Once an episode has terminated or been truncated, ``step``
raises ``RuntimeError`` until :meth:`~LaneKeeping.reset`; the recording ends with the
episode's last step.

``info`` after each step: ``t`` (zero at the end of the run-in), ``s`` (m), ``kappa``,
``y_L``, ``psi_L``, ``a_y`` (lateral acceleration, m/s^2), ``action`` (applied),
``clipped_actions`` so far. :meth:`LaneKeeping.recording` returns the episode as a
:class:`~manualcontrol.envs.recording.Recording`.

Rendering: the road from above around the car, heading up (``"rgb_array"``: a
``(400, 600, 3)`` uint8 frame; ``"human"``: a pygame window): lane edges, centre line,
the car, and the near (blue) and far (yellow) points.

The car's sample step (:func:`lane_step`, :func:`perceive`) is compiled by numba in
:mod:`~manualcontrol.envs._driving_kernels`, imported at the first reset: the driver
model's module imports this one, and an identification of the driver, which runs in C,
never imports numba.

Example::

    >>> import gymnasium as gym
    >>> import manualcontrol.envs
    >>> env = gym.make("ManualControl/LaneKeeping-v0", measurement_time=10.0)
    >>> observation, info = env.reset(seed=0)
    >>> observation.shape
    (4,)
    >>> observation, reward, terminated, truncated, info = env.step([0.0])
    >>> round(info["s"], 3)
    0.178
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from manualcontrol.envs._lazy import LazyKernel, kernels_on_first_use
from manualcontrol.envs._render import close_window, render_display
from manualcontrol.envs._validation import (
    check_bool,
    check_choice,
    check_int,
    check_options,
    check_positive,
    check_real,
    clip_action,
    reject_unknown,
    step_action,
)
from manualcontrol.envs.dynamics import discretize
from manualcontrol.envs.recording import Recording

if TYPE_CHECKING:
    from manualcontrol.envs._driving_kernels import lane_step, perceive

__all__ = [
    "DEFAULT_SPEED",
    "OBSERVATION_NAMES",
    "REWARDS",
    "ROAD_PRESETS",
    "STEERING_MODES",
    "VEHICLE_PRESETS",
    "LaneKeeping",
    "LaneKeepingModel",
    "Road",
    "RoadSegment",
    "VehicleParameters",
    "lane_keeping_model",
    "lane_step",
    "perceive",
    "road_preset",
    "vehicle_preset",
]

FloatArray = NDArray[np.float64]

#: 64 km/h (Zhao et al. 2019, Sec. 5.1), in m/s.
DEFAULT_SPEED = 64.0 / 3.6
GRAVITY = 9.81
STEERING_MODES: tuple[str, ...] = ("torque", "angle")
REWARDS: tuple[str, ...] = ("bounded", "squared_offset", "squared_offset_and_effort")
#: Names of the observation entries (the driver model's inputs, Zhao eq. 2).
OBSERVATION_NAMES: tuple[str, ...] = ("theta_far", "theta_near", "delta_d", "Gamma_s")
_DEFAULT_BOUND = {"torque": 20.0, "angle": 2.0}
_SCREEN = (600, 400)
_RESET_OPTIONS = ("road_seed",)


# ------------------------------------------------------------------------ vehicle


@dataclass(frozen=True)
class VehicleParameters:
    """A car for the lane-keeping task (see the module docstring for the equations).

    Parameters
    ----------
    c_f, c_r : float
        Front and rear cornering stiffness per tyre (N/rad).
    mass : float
        Mass ``m`` (kg).
    I_z : float
        Yaw moment of inertia (kg m^2).
    l_f, l_r : float
        Distances of the front and rear axle from the centre of gravity (m).
    R_s : float
        Steering ratio (steering-wheel angle over road-wheel angle).
    eta_t : float
        Pneumatic trail (m).
    K_m : float
        Manual part of the self-aligning torque felt at the wheel (power assistance).
    mu : float
        Road adhesion (the friction limit of loss of control).
    J_s, B_s : float
        Steering column inertia (kg m^2) and damping (N m s/rad).
    k_s : float
        Column stiffness per speed (N m s/rad per m, ``K_s = k_s v_x``).
    width : float
        Vehicle width (m), for lane departure.

    """

    c_f: float = 51_845.0
    c_r: float = 54_610.0
    mass: float = 1_834.9
    I_z: float = 2_800.0
    l_f: float = 1.249
    l_r: float = 1.56
    R_s: float = 14.5405
    eta_t: float = 0.245
    K_m: float = 0.031
    mu: float = 0.8
    J_s: float = 0.05
    B_s: float = 0.8
    k_s: float = 1.0
    width: float = 1.8

    def __post_init__(self) -> None:
        for item in dataclasses.fields(self):
            allow_zero = item.name in ("K_m", "eta_t", "B_s", "k_s")
            value = check_positive(item.name, getattr(self, item.name), allow_zero=allow_zero)
            object.__setattr__(self, item.name, value)

    def to_dict(self) -> dict[str, float]:
        """JSON-able form."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> VehicleParameters:
        """Inverse of :meth:`to_dict`; unknown keys raise."""
        reject_unknown("vehicle", data, [f.name for f in dataclasses.fields(cls)])
        return cls(**dict(data))


#: Vehicle presets: ``"mid-size"`` (the module docstring's values).
VEHICLE_PRESETS: tuple[str, ...] = ("mid-size",)


def vehicle_preset(spec: str | VehicleParameters | Mapping[str, Any]) -> VehicleParameters:
    """A vehicle from a preset name, a :class:`VehicleParameters` or its dict.

    A dict may name a ``preset`` and override some of its values.
    """
    if isinstance(spec, VehicleParameters):
        return spec
    if isinstance(spec, str):
        check_choice("vehicle", spec, VEHICLE_PRESETS)
        return VehicleParameters()
    if isinstance(spec, Mapping):
        data = dict(spec)
        base = vehicle_preset(data.pop("preset", "mid-size"))
        reject_unknown("vehicle", data, [f.name for f in dataclasses.fields(VehicleParameters)])
        return dataclasses.replace(base, **data)
    raise TypeError(f"vehicle must be a preset name, VehicleParameters or a dict, got {spec!r}")


# --------------------------------------------------------------------------- road

_SEGMENT_KINDS = ("straight", "clothoid", "arc")


@dataclass(frozen=True)
class RoadSegment:
    """A stretch of road: its length (m) and the curvature (1/m) at its start and end.

    ``"straight"``: zero curvature; ``"arc"``: constant ``start`` (= ``end``);
    ``"clothoid"``: curvature linear in the path length from ``start`` to ``end``.
    """

    kind: str
    length: float
    start: float = 0.0
    end: float = 0.0

    def __post_init__(self) -> None:
        check_choice("segment kind", self.kind, _SEGMENT_KINDS)
        object.__setattr__(self, "length", check_positive("segment length", self.length))
        start = check_real("segment start curvature", self.start)
        end = check_real("segment end curvature", self.end)
        if self.kind == "straight" and (start != 0.0 or end != 0.0):
            raise ValueError(f"a straight has zero curvature, got start={start!r}, end={end!r}")
        if self.kind == "arc" and start != end:
            raise ValueError(f"an arc has one curvature, got start={start!r} and end={end!r}")
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "end", end)

    @classmethod
    def straight(cls, length: float) -> RoadSegment:
        """A straight of ``length`` m."""
        return cls("straight", length)

    @classmethod
    def arc(cls, length: float, curvature: float) -> RoadSegment:
        """An arc of constant ``curvature`` (1/m; positive: left bend) over ``length`` m."""
        return cls("arc", length, curvature, curvature)

    @classmethod
    def clothoid(cls, length: float, start: float, end: float) -> RoadSegment:
        """A clothoid: curvature from ``start`` to ``end`` linearly over ``length`` m."""
        return cls("clothoid", length, start, end)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"kind": self.kind, "length": self.length, "start": self.start, "end": self.end}


@dataclass(frozen=True)
class Road:
    """A road as its curvature along the path: a sequence of :class:`RoadSegment`.

    ``Road.bend(...)`` builds the usual clothoid-arc-clothoid curve; :meth:`random`
    draws a seeded road of straights and bends; :func:`road_preset` gives named ones.
    """

    segments: tuple[RoadSegment, ...]
    name: str = ""

    def __post_init__(self) -> None:
        segments = tuple(
            s if isinstance(s, RoadSegment) else RoadSegment(**dict(s)) for s in self.segments
        )
        if not segments:
            raise ValueError("a road needs at least one segment")
        object.__setattr__(self, "segments", segments)
        starts = np.concatenate(([0.0], np.cumsum([s.length for s in segments])))
        object.__setattr__(self, "_starts", starts)
        object.__setattr__(self, "_from", np.array([s.start for s in segments]))
        object.__setattr__(self, "_to", np.array([s.end for s in segments]))

    @property
    def length(self) -> float:
        """Total length (m)."""
        return float(self._starts[-1])  # type: ignore[attr-defined]

    def curvature(self, s: Any) -> Any:
        """Curvature (1/m) at path length(s) ``s`` (m); 0 before the start and past the end."""
        s = np.asarray(s, dtype=np.float64)
        starts = self._starts  # type: ignore[attr-defined]
        index = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(self.segments) - 1)
        lengths = starts[index + 1] - starts[index]
        fraction = np.clip((s - starts[index]) / lengths, 0.0, 1.0)
        kappa_from = self._from[index]  # type: ignore[attr-defined]
        kappa_to = self._to[index]  # type: ignore[attr-defined]
        values = kappa_from + (kappa_to - kappa_from) * fraction
        values = np.where((s < 0.0) | (s >= starts[-1]), 0.0, values)
        return float(values) if values.ndim == 0 else values

    def geometry(self, step: float = 0.5) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Centre line ``(s, x, y, heading)`` about every ``step`` m from the start.

        The heading integrates the curvature by the midpoint rule (exact for the
        piecewise-linear curvature within segments), the position by the trapezoidal rule.
        """
        step = check_positive("step", step)
        count = max(2, math.ceil(self.length / step) + 1)
        s = np.linspace(0.0, self.length, count)
        ds = np.diff(s)
        heading = np.concatenate(([0.0], np.cumsum(ds * self.curvature(s[:-1] + 0.5 * ds))))
        x = np.concatenate(
            ([0.0], np.cumsum(0.5 * ds * (np.cos(heading[1:]) + np.cos(heading[:-1]))))
        )
        y = np.concatenate(
            ([0.0], np.cumsum(0.5 * ds * (np.sin(heading[1:]) + np.sin(heading[:-1]))))
        )
        return s, x, y, heading

    @staticmethod
    def bend(curvature: float, arc: float, transition: float) -> tuple[RoadSegment, ...]:
        """A bend: clothoid in over ``transition`` m, arc of ``arc`` m, clothoid out."""
        return (
            RoadSegment.clothoid(transition, 0.0, curvature),
            RoadSegment.arc(arc, curvature),
            RoadSegment.clothoid(transition, curvature, 0.0),
        )

    @classmethod
    def random(
        cls,
        seed: int | np.random.Generator,
        length: float = 4_000.0,
        *,
        radius: tuple[float, float] = (200.0, 800.0),
        arc: tuple[float, float] = (40.0, 200.0),
        transition: tuple[float, float] = (30.0, 80.0),
        straight: tuple[float, float] = (20.0, 200.0),
    ) -> Road:
        """A seeded random road of at least ``length`` m.

        It starts with a straight, then alternates bends and straights: each bend turns
        left or right with equal chance, radius uniform in ``radius`` (m), arc and
        clothoid lengths uniform in ``arc`` and ``transition``, straights in ``straight``.
        The defaults keep the lateral acceleration at 64 km/h below 1.6 m/s^2.
        """
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        length = check_positive("length", length)
        for name, (low, high) in (
            ("radius", radius),
            ("arc", arc),
            ("transition", transition),
            ("straight", straight),
        ):
            check_positive(f"{name}[0]", low)
            if not high >= low:
                raise ValueError(
                    f"{name} must be a (low, high) pair with high >= low, got {(low, high)!r}"
                )
        segments = [RoadSegment.straight(rng.uniform(*straight))]
        total = segments[0].length
        while total < length:
            curvature = rng.choice((-1.0, 1.0)) / rng.uniform(*radius)
            bend = cls.bend(curvature, rng.uniform(*arc), rng.uniform(*transition))
            segments += [*bend, RoadSegment.straight(rng.uniform(*straight))]
            total += sum(s.length for s in bend) + segments[-1].length
        name = f"random({seed})" if not isinstance(seed, np.random.Generator) else "random"
        return cls(tuple(segments), name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"name": self.name, "segments": [s.to_dict() for s in self.segments]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Road:
        """Inverse of :meth:`to_dict`."""
        reject_unknown("road", data, ("name", "segments"))
        if "segments" not in data:
            raise ValueError("road dict needs 'segments'")
        segments = []
        for i, item in enumerate(data["segments"]):
            if not isinstance(item, Mapping):
                raise TypeError(f"road segment {i} must be a dict, got {item!r}")
            reject_unknown(f"road segment {i}", item, ("kind", "length", "start", "end"))
            segments.append(RoadSegment(**dict(item)))
        return cls(tuple(segments), str(data.get("name", "")))


def _zhao2019_road() -> Road:
    """Bends of 250-500 m radius both ways between short straights, one 270-m straight.

    3.9 km: 220 s at 64 km/h. The long straight spans about 74-89 s (Zhao et al. 2019
    Fig. 5 discuss a straight from 80 to 90 s, where the perception angles vanish).
    """
    bend = Road.bend
    segments = (
        RoadSegment.straight(60.0),
        *bend(1 / 300, 100.0, 50.0),
        RoadSegment.straight(40.0),
        *bend(-1 / 250, 120.0, 50.0),
        RoadSegment.straight(50.0),
        *bend(1 / 400, 140.0, 50.0),
        RoadSegment.straight(40.0),
        *bend(-1 / 300, 110.0, 50.0),
        RoadSegment.straight(60.0),
        *bend(1 / 250, 90.0, 50.0),
        RoadSegment.straight(272.0),
        *bend(-1 / 350, 150.0, 60.0),
        RoadSegment.straight(40.0),
        *bend(1 / 300, 120.0, 50.0),
        RoadSegment.straight(60.0),
        *bend(-1 / 250, 100.0, 50.0),
        RoadSegment.straight(50.0),
        *bend(1 / 500, 160.0, 60.0),
        RoadSegment.straight(40.0),
        *bend(-1 / 300, 120.0, 50.0),
        RoadSegment.straight(50.0),
        *bend(1 / 280, 100.0, 50.0),
        RoadSegment.straight(50.0),
        *bend(-1 / 400, 130.0, 50.0),
        RoadSegment.straight(100.0),
        *bend(1 / 350, 120.0, 50.0),
        RoadSegment.straight(100.0),
    )
    return Road(segments, "zhao2019")


_ROADS = {
    "zhao2019": _zhao2019_road,
    "straight": lambda: Road((RoadSegment.straight(5_000.0),), "straight"),
}
#: Road presets (``"random"`` draws a road per episode in the environment).
ROAD_PRESETS: tuple[str, ...] = tuple(_ROADS)


def road_preset(spec: str | Road | Mapping[str, Any]) -> Road:
    """A road from a preset name, a :class:`Road` or its dict."""
    if isinstance(spec, Road):
        return spec
    if isinstance(spec, str):
        check_choice("road", spec, ROAD_PRESETS)
        return _ROADS[spec]()
    if isinstance(spec, Mapping):
        return Road.from_dict(spec)
    raise TypeError(f"road must be a preset name, a Road or a dict, got {spec!r}")


# ----------------------------------------------------------------- the sampled model


class LaneKeepingModel(NamedTuple):
    """The car discretised for one sample time, and how it is perceived.

    ``x[k+1] = phi x[k] + gamma[:, 0] action[k] + gamma[:, 1] kappa[k]`` (exact
    zero-order hold). States ``(v_y, r, psi_L, y_L, delta_d, delta_d')`` with torque
    steering, ``(v_y, r, psi_L, y_L, delta_d)`` with angle steering (``delta_d[k+1] =
    action[k]``). ``H`` (6, n) maps the state to ``theta_near, delta_d, Gamma_s, a_y,
    y_L, psi_L``; ``h_kappa`` (6,) adds the curvature at the car; ``far_gain`` scales
    the previewed curvature into ``theta_far``. ``packed`` (n + 6, n + 2) holds
    ``[phi | gamma]`` over ``[H | h_kappa | 0]`` for the compiled step.
    """

    phi: FloatArray
    gamma: FloatArray
    H: FloatArray
    h_kappa: FloatArray
    far_gain: float
    packed: FloatArray


def _continuous(vehicle: VehicleParameters, speed: float, steering: str, near: float):
    """``A, B`` (inputs action, curvature) and the perception rows (module docstring)."""
    v = vehicle
    n = 6 if steering == "torque" else 5
    # front and rear axle forces as rows over the state (delta_d is state 4)
    front = np.zeros(n)
    front[0] = -2.0 * v.c_f / speed
    front[1] = -2.0 * v.c_f * v.l_f / speed
    front[4] = 2.0 * v.c_f / v.R_s
    rear = np.zeros(n)
    rear[0] = -2.0 * v.c_r / speed
    rear[1] = 2.0 * v.c_r * v.l_r / speed
    A = np.zeros((n, n))
    B = np.zeros((n, 2))
    A[0] = (front + rear) / v.mass
    A[0, 1] -= speed
    A[1] = (v.l_f * front - v.l_r * rear) / v.I_z
    A[2, 1] = 1.0
    B[2, 1] = -speed
    A[3, 0] = 1.0
    A[3, 2] = speed
    aligning = -v.K_m * v.eta_t * front / v.R_s  # Gamma_s over the state
    if steering == "torque":
        A[4, 5] = 1.0
        A[5] = aligning / v.J_s
        A[5, 4] -= v.k_s * speed / v.J_s
        A[5, 5] -= v.B_s / v.J_s
        B[5, 0] = 1.0 / v.J_s
    H = np.zeros((6, n))
    h_kappa = np.zeros(6)
    H[0, 3] = -1.0 / near
    H[0, 2] = -1.0
    h_kappa[0] = 0.5 * near
    H[1, 4] = 1.0
    H[2] = aligning
    H[3] = (front + rear) / v.mass
    H[4, 3] = 1.0
    H[5, 2] = 1.0
    return A, B, H, h_kappa


def lane_keeping_model(
    vehicle: VehicleParameters,
    speed: float,
    steering: str,
    dt: float,
    near_distance: float = 5.0,
    far_gain: float = 15.0,
) -> LaneKeepingModel:
    """The :class:`LaneKeepingModel` of a car at ``speed`` (m/s) sampled at ``dt`` (s)."""
    check_choice("steering", steering, STEERING_MODES)
    A, B, H, h_kappa = _continuous(vehicle, speed, steering, near_distance)
    if steering == "torque":
        exact = discretize(A, B, dt)
        phi, gamma = exact.phi, exact.gamma
    else:
        # the wheel angle is the action, held: discretise the car with delta_d as input
        n = A.shape[0]
        A_car = A[:4, :4]
        B_car = np.column_stack([A[:4, 4], B[:4, 1]])
        exact = discretize(A_car, B_car, dt)
        phi = np.zeros((n, n))
        gamma = np.zeros((n, 2))
        phi[:4, :4] = exact.phi
        gamma[:4] = exact.gamma
        gamma[4, 0] = 1.0
    n = phi.shape[0]
    packed = np.zeros((n + 6, n + 2))
    packed[:n, :n] = phi
    packed[:n, n:] = gamma
    packed[n:, :n] = H
    packed[n:, n] = h_kappa
    return LaneKeepingModel(
        np.ascontiguousarray(phi),
        np.ascontiguousarray(gamma),
        np.ascontiguousarray(H),
        h_kappa,
        float(far_gain),
        packed,
    )


#: The numba kernels that moved to :mod:`~manualcontrol.envs._driving_kernels`, exported
#: here by name on first use.
_KERNELS = ("perceive", "lane_step")
__getattr__ = kernels_on_first_use(globals(), "manualcontrol.envs._driving_kernels", _KERNELS)


# --------------------------------------------------------------------- environment


class LaneKeeping(gym.Env[FloatArray, FloatArray]):
    """Lane keeping with a bicycle-model car; see :mod:`manualcontrol.envs.driving`.

    Parameters
    ----------
    road
        Road preset (``"zhao2019"``, ``"straight"``), ``"random"`` (a new seeded random
        road each episode; ``reset(options={"road_seed": k})`` picks one), a
        :class:`Road` or its dict.
    vehicle
        Vehicle preset (``"mid-size"``), :class:`VehicleParameters` or a dict.
    speed
        Constant speed (m/s), default 64 km/h.
    steering
        ``"torque"`` (default) or ``"angle"``.
    dt, run_in, measurement_time
        Sample time (s, default 0.01), run-in before ``t = 0`` (s, default 0),
        measured time (s; default the time the road takes, 120 s for random roads).
    near_distance, far_gain, far_preview
        Near-point distance (m, 5), far-point gain distance (m, 15) and how far ahead
        the far point reads the curvature (m, 15).
    lane_width
        Lane width (m, 3.5).
    action_bound
        Action limit, default 20 N m (torque) or 2 rad (angle).
    reward, reward_scale, effort_weight
        See the module docstring.
    include_rates, include_previous_action
        Observation extras, off by default.
    loss_of_control
        Terminate on lane departure or skid (default True).
    render_mode
        None, ``"rgb_array"`` or ``"human"``.

    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 50}
    # read at the first reset, so that a process that only builds the environment, or
    # imports it for the driver model's records, never imports numba
    _perceive = LazyKernel("manualcontrol.envs._driving_kernels", "perceive")
    _lane_step = LazyKernel("manualcontrol.envs._driving_kernels", "lane_step")

    def __init__(
        self,
        road: str | Road | Mapping[str, Any] = "zhao2019",
        vehicle: str | VehicleParameters | Mapping[str, Any] = "mid-size",
        *,
        speed: float = DEFAULT_SPEED,
        steering: str = "torque",
        dt: float = 0.01,
        run_in: float = 0.0,
        measurement_time: float | None = None,
        near_distance: float = 5.0,
        far_gain: float = 15.0,
        far_preview: float = 15.0,
        lane_width: float = 3.5,
        action_bound: float | None = None,
        reward: str = "bounded",
        reward_scale: float = 0.25,
        effort_weight: float = 0.0,
        include_rates: bool = False,
        include_previous_action: bool = False,
        loss_of_control: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.random_road = isinstance(road, str) and road == "random"
        self.road = None if self.random_road else road_preset(road)
        self.vehicle = vehicle_preset(vehicle)
        self.speed = check_positive("speed", speed)
        self.steering = check_choice("steering", steering, STEERING_MODES)
        self.dt = check_positive("dt", dt)
        self.run_in = check_positive("run_in", run_in, allow_zero=True)
        self.near_distance = check_positive("near_distance", near_distance)
        self.far_gain = check_positive("far_gain", far_gain, allow_zero=True)
        self.far_preview = check_positive("far_preview", far_preview, allow_zero=True)
        self.lane_width = check_positive("lane_width", lane_width)
        self.lane_limit = 0.5 * (self.lane_width - self.vehicle.width)
        if self.lane_limit <= 0.0:
            raise ValueError(
                f"lane_width must exceed the vehicle width {self.vehicle.width:g} m, "
                f"got {lane_width!r}"
            )
        if measurement_time is None:
            if self.road is None:
                measurement_time = 120.0
            else:
                measurement_time = self.road.length / self.speed - self.run_in
        self.measurement_time = check_positive("measurement_time", measurement_time)
        self.n_run_in = round(self.run_in / self.dt)
        self.episode_steps = self.n_run_in + round(self.measurement_time / self.dt)
        if self.episode_steps < 1:
            raise ValueError(
                f"measurement_time must be at least one sample ({self.dt:g} s), got "
                f"{measurement_time!r}"
            )
        if self.road is not None:
            needed = self.speed * self.episode_steps * self.dt
            if needed > self.road.length + 1e-9:
                raise ValueError(
                    f"measurement_time must fit the road: {self.road.length:.1f} m at "
                    f"{self.speed:g} m/s last {self.road.length / self.speed:.2f} s, the "
                    f"episode asks {self.episode_steps * self.dt:.2f} s (run_in included)"
                )
        bound = _DEFAULT_BOUND[self.steering] if action_bound is None else action_bound
        self.action_bound = check_positive("action_bound", bound)
        self.reward_kind = check_choice("reward", reward, REWARDS)
        self.reward_scale = check_positive("reward_scale", reward_scale)
        self.effort_weight = check_positive("effort_weight", effort_weight, allow_zero=True)
        self.include_rates = check_bool("include_rates", include_rates)
        self.include_previous_action = check_bool(
            "include_previous_action", include_previous_action
        )
        self.loss_of_control = check_bool("loss_of_control", loss_of_control)
        if render_mode is not None:
            check_choice("render_mode", render_mode, self.metadata["render_modes"])
        self.render_mode = render_mode
        self.model = lane_keeping_model(
            self.vehicle, self.speed, self.steering, self.dt, self.near_distance, self.far_gain
        )
        self.skid_limit = self.vehicle.mu * GRAVITY
        self.time_origin = -self.n_run_in * self.dt
        self._time = self.time_origin + np.arange(self.episode_steps + 1) * self.dt
        self._s = self.speed * self.dt * np.arange(self.episode_steps + 1)
        self.action_space = spaces.Box(-self.action_bound, self.action_bound, (1,), np.float64)
        size = 4 * (2 if self.include_rates else 1) + self.include_previous_action
        low = np.full(size, -np.inf)
        high = np.full(size, np.inf)
        if self.include_previous_action:
            low[-1], high[-1] = -self.action_bound, self.action_bound
        self.observation_space = spaces.Box(low, high, dtype=np.float64)
        self._screen: Any = None
        self._clock: Any = None
        self._geometry: Any = None
        self._k = -1
        self._clipped = 0
        # why the episode ended (for step's error), None while it runs
        self._ended: str | None = None

    # ------------------------------------------------------------------- API

    @property
    def times(self) -> FloatArray:
        """Times of the episode's observations (s), ``episode_steps + 1`` of them."""
        return self._time.copy()

    def episode_curvature(self) -> tuple[FloatArray, FloatArray]:
        """Curvature at the car and at the far point for every observation of the episode."""
        if self._k < 0:
            raise RuntimeError("call reset() first: the episode's road is drawn there")
        return np.array(self._kappa), np.array(self._kappa_far)

    def episode_road(self, road_seed: int | None = None) -> Road:
        """The road of an episode (a fixed road, or the random road of ``road_seed``)."""
        if self.road is not None:
            return self.road
        if road_seed is None:
            road_seed = int(self.np_random.integers(2**31))
        length = self.speed * self.dt * self.episode_steps + self.far_preview + 1.0
        return Road.random(check_int("road_seed", road_seed, minimum=0), length)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Start at rest on the lane centre; ``options={"road_seed": k}`` for random roads."""
        super().reset(seed=seed)
        options = check_options(options, _RESET_OPTIONS, example={"road_seed": 0})
        if "road_seed" in options and self.road is not None:
            raise ValueError("reset option road_seed applies to road='random' only")
        road = self.episode_road(options.get("road_seed"))
        self.current_road = road
        # Python floats: indexing a list is cheaper than a numpy array in the step
        self._kappa = road.curvature(self._s).tolist()
        self._kappa_far = road.curvature(self._s + self.far_preview).tolist()
        n = self.episode_steps
        self._k = 0
        self._state = np.zeros(2 * self.model.phi.shape[0])
        self._perceived = np.zeros((n + 1, 7))
        self._actions = np.zeros(n)
        self._previous_action = 0.0
        self._clipped = 0
        self._ended = None
        self._geometry = None
        m = self.model
        # a step calls the kernel from the instance: reading the class's LazyKernel at
        # every step would cost about 5 % of it
        self._car_step = self._lane_step
        self._perceive(
            m.packed,
            m.far_gain,
            self._state,
            self._kappa[0],
            self._kappa_far[0],
            self._perceived,
            0,
        )
        if self.render_mode == "human":
            self.render()
        return self._observe(0), self._info(0, 0.0)

    def step(self, action: FloatArray) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        """Apply ``action[0]`` over one sample; see the module docstring.

        Raises ``RuntimeError`` before :meth:`reset` and after the episode has
        terminated or been truncated.
        """
        k = self._k
        u = step_action(action, k, self._ended)
        bound = self.action_bound
        if not -bound <= u <= bound:
            u = clip_action(u, bound, action)
            self._clipped += 1
        kappa = self._kappa
        perceived = self._perceived
        self._car_step(
            self.model.packed,
            self.far_gain,
            self._state,
            u,
            kappa[k],
            kappa[k + 1],
            self._kappa_far[k + 1],
            perceived,
            k + 1,
        )
        self._actions[k] = u
        k += 1
        self._k = k
        self._previous_action = u
        row = perceived[k]
        *_, a_y, y_L, psi_L = row.tolist()
        offset = y_L / self.reward_scale
        if self.reward_kind == "bounded":
            reward = 1.0 / (1.0 + offset * offset)
        elif self.reward_kind == "squared_offset":
            reward = -offset * offset
        else:
            effort = u / bound
            reward = -offset * offset - self.effort_weight * effort * effort
        terminated = self.loss_of_control and (
            abs(y_L) > self.lane_limit or abs(a_y) > self.skid_limit
        )
        truncated = k >= self.episode_steps
        if terminated or truncated:
            self._ended = self._end_reason(k, terminated, y_L, a_y)
        if self.include_rates or self.include_previous_action:
            observation = self._observe(k)
        else:
            observation = row[:4].copy()
        if self.render_mode == "human":
            self.render()
        info = {
            "t": self.time_origin + k * self.dt,
            "s": self.speed * self.dt * k,
            "kappa": kappa[k],
            "y_L": y_L,
            "psi_L": psi_L,
            "a_y": a_y,
            "action": u,
            "clipped_actions": self._clipped,
        }
        return observation, reward, terminated, truncated, info

    def _end_reason(self, k: int, terminated: bool, y_L: float, a_y: float) -> str:
        t = self.time_origin + k * self.dt
        if not terminated:
            return f"truncated after {k} steps, at t = {t:g} s"
        if abs(y_L) > self.lane_limit:
            why = f"the car left its lane, |y_L| = {abs(y_L):.3g} m > {self.lane_limit:g} m"
        else:
            why = (
                f"the car lost grip, |a_y| = {abs(a_y):.3g} m/s^2 > mu g = "
                f"{self.skid_limit:.3g} m/s^2"
            )
        return f"terminated at t = {t:g} s: {why}"

    def _observe(self, k: int) -> FloatArray:
        row = self._perceived[k]
        parts = [row[:4]]
        if self.include_rates:
            rates = np.zeros(4) if k == 0 else (row[:4] - self._perceived[k - 1, :4]) / self.dt
            parts.append(rates)
        if self.include_previous_action:
            parts.append(np.array([self._previous_action]))
        return np.concatenate(parts)

    def _info(self, k: int, u: float) -> dict[str, Any]:
        _, _, _, _, a_y, y_L, psi_L = self._perceived[k].tolist()
        return {
            "t": self.time_origin + k * self.dt,
            "s": self.speed * self.dt * k,
            "kappa": self._kappa[k],
            "y_L": y_L,
            "psi_L": psi_L,
            "a_y": a_y,
            "action": u,
            "clipped_actions": self._clipped,
        }

    def recording(self, include_run_in: bool = False) -> Recording:
        """The steps so far as a Recording (run-in cut unless ``include_run_in``).

        Signals ``t``, the four observations (``theta_far, theta_near, delta_d,
        Gamma_s``), ``kappa``, ``y_L``, ``psi_L``, ``a_y`` and the action: ``Gamma_d``
        (torque steering) or ``delta_command`` (angle steering), at every sample at
        which an action was taken (the observation after the last step is left out).
        After a termination the episode's steps end there, and so does the recording.
        """
        steps = self._k
        if steps <= 0:
            raise RuntimeError("no steps taken yet: reset() and step() first")
        start = 0 if include_run_in else min(self.n_run_in, steps - 1)
        window = slice(start, steps)
        rows = self._perceived[window]
        actions = self._actions[window]
        signals = {
            "t": self._time[window],
            **{name: rows[:, i] for i, name in enumerate(OBSERVATION_NAMES)},
            "kappa": np.asarray(self._kappa)[window],
            "y_L": rows[:, 5],
            "psi_L": rows[:, 6],
            "a_y": rows[:, 4],
            ("Gamma_d" if self.steering == "torque" else "delta_command"): actions,
        }
        return Recording(signals=signals, dt=self.dt, metadata=self.describe())

    def describe(self) -> dict[str, Any]:
        """What a recording of this environment says about how it was made.

        Raises ``RuntimeError`` before :meth:`reset`: the episode's road (drawn there
        for ``road="random"``) and its clipped actions are not known until then.
        """
        if self._k < 0:
            raise RuntimeError(
                "call reset() before describe(): it reports the episode's road and "
                "clipped actions, which reset() sets up"
            )
        return {
            "task": "lane-keeping",
            "road": self.current_road.to_dict(),
            "vehicle": self.vehicle.to_dict(),
            "speed": self.speed,
            "steering": self.steering,
            "dt": self.dt,
            "run_in": self.run_in,
            "measurement_time": self.measurement_time,
            "near_distance": self.near_distance,
            "far_gain": self.far_gain,
            "far_preview": self.far_preview,
            "lane_width": self.lane_width,
            "clipped_actions": self._clipped,
            "source": "manualcontrol.envs.driving.LaneKeeping",
        }

    # -------------------------------------------------------------- rendering

    def render(self) -> NDArray[np.uint8] | None:
        """Draw the road from above around the car (see the module docstring)."""
        return render_display(self, _SCREEN)

    def _draw(self, canvas: Any, pygame: Any) -> None:
        width, height = _SCREEN
        canvas.fill((40, 110, 50))
        k = max(self._k, 0)
        if self._geometry is None:
            self._geometry = self.current_road.geometry(0.5)
        s_grid, x_grid, y_grid, heading_grid = self._geometry
        s_car = self.speed * self.dt * k
        _, _, _, _, _, y_L, psi_L = self._perceived[k].tolist()
        heading_road = float(np.interp(s_car, s_grid, heading_grid))
        normal = (-math.sin(heading_road), math.cos(heading_road))
        car_x = float(np.interp(s_car, s_grid, x_grid)) + y_L * normal[0]
        car_y = float(np.interp(s_car, s_grid, y_grid)) + y_L * normal[1]
        car_heading = heading_road + psi_L
        scale = 8.0  # px per m
        cos_h, sin_h = math.cos(car_heading), math.sin(car_heading)
        anchor = (width / 2, 0.75 * height)

        def screen(px: float, py: float) -> tuple[float, float]:
            # car frame: forward up the screen, left to the left
            dx, dy = px - car_x, py - car_y
            forward = dx * cos_h + dy * sin_h
            left = -dx * sin_h + dy * cos_h
            return anchor[0] - scale * left, anchor[1] - scale * forward

        ahead = (s_grid >= s_car - 15.0) & (s_grid <= s_car + 45.0)
        xs, ys, hs = x_grid[ahead], y_grid[ahead], heading_grid[ahead]
        half = 0.5 * self.lane_width
        pygame.draw.polygon(
            canvas,
            (70, 70, 75),
            [
                screen(x - half * math.sin(h), y + half * math.cos(h))
                for x, y, h in zip(xs, ys, hs, strict=True)
            ]
            + [
                screen(x + half * math.sin(h), y - half * math.cos(h))
                for x, y, h in zip(xs[::-1], ys[::-1], hs[::-1], strict=True)
            ],
        )
        for side in (-1.0, 1.0):
            edge = [
                screen(x - side * half * math.sin(h), y + side * half * math.cos(h))
                for x, y, h in zip(xs, ys, hs, strict=True)
            ]
            pygame.draw.lines(canvas, (235, 235, 235), False, edge, 2)
        centre = [screen(x, y) for x, y in zip(xs, ys, strict=True)]
        for i in range(0, len(centre) - 4, 12):
            pygame.draw.line(canvas, (220, 220, 120), centre[i], centre[i + 4], 1)
        car_width = self.vehicle.width
        corners = [
            (anchor[0] + scale * side * car_width / 2, anchor[1] - scale * along)
            for along, side in ((2.7, -1), (2.7, 1), (-1.8, 1), (-1.8, -1))
        ]
        pygame.draw.polygon(canvas, (200, 40, 40), corners)
        near = (anchor[0], anchor[1] - scale * self.near_distance)
        pygame.draw.circle(canvas, (80, 200, 255), (int(near[0]), int(near[1])), 4)
        s_far = s_car + self.far_preview
        far = screen(
            float(np.interp(s_far, s_grid, x_grid)), float(np.interp(s_far, s_grid, y_grid))
        )
        pygame.draw.circle(canvas, (240, 200, 60), (int(far[0]), int(far[1])), 5, 2)

    def close(self) -> None:
        """Close the pygame window, if any."""
        close_window(self)
