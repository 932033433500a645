"""Evaluating a trained agent the way a human operator is evaluated.

:func:`evaluate` lets the agent (through its human-limitation wrappers) fly one full
measurement run, then reports what a manual-control researcher looks at: the RMS
tracking error (beside a precision-model pilot with typical parameters on the same
forcing), the open-loop frequency response at the forcing frequencies with crossover
frequency and phase margin, and the identified parameters of the equivalent
cybernetic pilot model, to hold against the limitations imposed (is the identified
delay the imposed action delay?): by an offline output-error fit (exact delay,
constant parameters; on ``K/s`` the lead ``K_v`` held at 0, the single integrator's
rule that the describing-function fit and the filters follow too: free there, the fit
traded a negative lead against a vanishing delay) and by the DEKF (its estimates
averaged over the measurement, after converging on the run-in), and, on a
compensatory task, the human-likeness
figures of :func:`~manualcontrol.estimators.analysis.human_likeness.human_likeness` (crossover,
phase margin, effective delay, pilot gain flatness or lead, remnant, RMS ratio) with
its verdict.

The run keeps the wrappers' noise (observation and motor noise: the agent's remnant)
unless ``deterministic`` asks otherwise: a human is measured with their remnant, and
the remnant fraction of a noise-free run is zero, which no human shows.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from manualcontrol.agents.training import TASK_IDS, TrainedAgent, make_env
from manualcontrol.envs._files import atomic_path, atomic_write
from manualcontrol.envs._validation import check_int
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.tasks import TASKS_BY_NAME
from manualcontrol.estimators.analysis.frequency import (
    FrequencyResponse,
    forcing_frequency_response,
)
from manualcontrol.estimators.analysis.human_likeness import (
    HumanLikeness,
    human_likeness,
    plot_human_likeness,
    reference_model,
    reference_pilot,
)
from manualcontrol.estimators.offline.output_error import OfflineFit, fit_pilot
from manualcontrol.estimators.protocol import report_progress
from manualcontrol.pilots import Pilot

__all__ = [
    "LANE_KEEPING_ROADS",
    "REFERENCE_PILOTS",
    "Evaluation",
    "LaneKeepingEvaluation",
    "evaluate",
    "evaluate_lane_keeping",
    "fly",
    "write_lane_keeping_report",
    "write_report",
]

#: Typical precision-model pilots of the thesis's elements (Table 6.1: SI values of Sim 2
#: without preview, DI values of Sim 8), as :func:`~manualcontrol.estimators.
#: human_likeness.reference_pilot` gives them (every element: that function).
REFERENCE_PILOTS: dict[str, dict[str, float]] = {
    name: reference_pilot(name) for name in ("SI", "DI")
}


@dataclass(frozen=True)
class Evaluation:
    """What :func:`evaluate` measured for one run of the agent.

    ``human`` holds the human-likeness figures and verdict (None on a pursuit or
    preview task, which they do not describe); ``noise`` whether the wrappers' noise was
    on in the run; ``config`` the agent's training configuration. ``dekf`` is empty on
    a pure gain, where the DEKF's model (no lag) cannot describe an operator who
    integrates and ``identified`` is the precision model with its lag.
    """

    rms_error: float
    reference_rms_error: float | None
    frequency_response: FrequencyResponse
    identified: OfflineFit
    dekf: Mapping[str, float]
    limitations: tuple[Mapping[str, Any], ...]
    recording: Recording
    human: HumanLikeness | None = None
    noise: bool = True
    config: Any = None
    periods: int = 1

    def summary(self) -> dict[str, Any]:
        """Plain numbers for tables and JSON."""
        return {
            "rms_error": self.rms_error,
            "reference_rms_error": self.reference_rms_error,
            # the plain RMS against the typical pilot flown without noise: not the
            # human-likeness rms_ratio, which gives that pilot the run's remnant
            "bare_task_rms_ratio": (
                None
                if self.reference_rms_error is None
                else self.rms_error / self.reference_rms_error
            ),
            "crossover_frequency": self.frequency_response.crossover_frequency,
            "phase_margin": self.frequency_response.phase_margin,
            "identified": dict(self.identified.parameters),
            "identification_vaf": self.identified.vaf,
            "dekf": dict(self.dekf),
            "limitations": [dict(limit) for limit in self.limitations],
            "noise": self.noise,
            "periods": self.periods,
            "human_likeness": None if self.human is None else self.human.to_dict(),
            "implausible": implausible(
                _identified_structure(self.identified),
                {f"fit {k}": v for k, v in self.identified.parameters.items()},
            )
            + implausible(self.identified.model, {f"DEKF {k}": v for k, v in self.dekf.items()}),
        }


def implausible(model: Any, values: dict[str, float]) -> list[str]:
    """Identified values a user should not trust, each as a sentence.

    Flagged: below the valid or human range, beyond twice the human maximum, or under
    half the human minimum (a negative gain, a neuromuscular damping of 80 ...). Keys
    may carry a prefix ("fit K_p"). ``model``: the structure identified, or its name.
    """
    from manualcontrol.pilots import make_model

    structure = make_model(model)
    flags = []
    for key, value in values.items():
        name = key.split()[-1]
        if name not in structure.parameter_names or not np.isfinite(value):
            if not np.isfinite(value):
                flags.append(f"{key} = {value} is not finite")
            continue
        spec = structure.spec(name)
        low, high = spec.human
        if (
            value < min(spec.valid[0], low)
            or value > max(2.0 * high, spec.valid[0])
            or (low > 0.0 and value < 0.5 * low)
        ):
            flags.append(
                f"{key} = {value:.4g} {spec.unit} is far outside the human range "
                f"[{low:g}, {high:g}]"
            )
    return flags


def fly(actor: Any, env: Any, seed: int, *, include_run_in: bool = False) -> Recording:
    """One episode of ``actor`` (an agent or any pilot with ``reset``/``act``) in ``env``."""
    observation, _ = env.reset(seed=seed)
    actor.reset(seed=seed, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(actor.act(observation))
        done = terminated or truncated
    return env.unwrapped.recording(include_run_in=include_run_in)


def _make_env(agent: TrainedAgent, noise: bool, overrides: Mapping[str, Any]) -> Any:
    """The agent's wrapped env, its noise on or off where ``make_env`` can say so."""
    if "noise" in inspect.signature(make_env).parameters:
        return make_env(agent.config, noise=noise, **overrides)
    return make_env(agent.config, **overrides)  # an older make_env: its noise always on


def evaluate(
    agent: TrainedAgent,
    *,
    seed: int = 0,
    run_in: float = 10.0,
    env_overrides: Mapping[str, Any] | None = None,
    reference: Mapping[str, float] | None = None,
    deterministic: bool | None = None,
    periods: int = 1,
) -> Evaluation:
    """Run the agent over ``periods`` whole forcing periods and identify it.

    The environment is the agent's own (configuration, wrappers), over ``periods``
    times the measurement time of the forcing (for the frequency response) after
    ``run_in`` seconds, with loss-of-control termination off so that a poor agent is
    still measured over the whole run. With several periods the describing function
    and the human-likeness figures read the Fourier coefficients of every period
    together, as a laboratory averages a participant's repeated runs of one condition
    (the periodic forcing repeats exactly and the remnant does not, so the remnant's
    variance in each line's estimate falls with the number of periods).
    ``reference`` overrides the typical precision pilot of the agent's element
    (:func:`~manualcontrol.estimators.analysis.human_likeness.reference_pilot`; an
    element without one, e.g. the critical task, needs one given), in the RMS comparison here
    and in the human-likeness ratio.
    ``deterministic`` True runs without the wrappers' noise; None (default) follows the
    agent's configuration (``TrainingConfig.deterministic``, where it has one), whose
    default keeps the noise on.
    """
    if deterministic is None:
        deterministic = bool(getattr(agent.config, "deterministic", False))
    if deterministic not in (True, False):
        raise TypeError(f"deterministic must be True, False or None, got {deterministic!r}")
    periods = check_int("periods", periods, minimum=1)
    if periods > 1 and (env_overrides or {}).get("measurement_time") is not None:
        raise ValueError(
            "give periods or env_overrides['measurement_time'], not both: periods "
            f"({periods}) measures over that many forcing periods"
        )
    overrides = {
        "measurement_time": None,
        "run_in": run_in,
        "loss_of_control": None,
        **dict(env_overrides or {}),
    }
    env = _make_env(agent, not deterministic, overrides)
    if periods > 1:
        # the forcing's period is what the env measures over by default
        overrides["measurement_time"] = periods * env.unwrapped.measurement_time
        env.close()
        env = _make_env(agent, not deterministic, overrides)
    span = "one forcing period" if periods == 1 else f"{periods} forcing periods"
    report_progress(f"evaluate: flying the agent over {span} after {run_in:g} s")
    fly(agent, env, seed)
    whole = env.unwrapped.recording(include_run_in=True)
    recording = whole.slice_time(0.0)
    env.close()
    rms = float(np.sqrt(np.mean(recording.e**2)))
    response = forcing_frequency_response(recording)
    display = TASKS_BY_NAME.get(agent.config.task)  # None on lane keeping: no tracking display
    model = "preview" if display is None else display.pilot_model
    structure = _fitted_structure(recording, model)
    report_progress(f"evaluate: fitting the {_structure_name(structure)} model (output error)")
    # simulated from the run-in's start, at rest as the agent was there, and fitted from 2 s
    # into the measurement (fit_pilot's skip): a slow equaliser (a lag of seconds on a
    # pure gain) carries its state into the measurement, which a model started at rest
    # at the measurement's start would have to fit as a transient
    identified = fit_pilot(
        whole,
        structure,
        fixed=_held_by_rule(recording, structure),
        skip=float(recording.t[0] - whole.t[0]) + 2.0,
    )
    if getattr(structure, "lag", False):
        # the DEKF's precision model has no lag: its values on an operator that
        # integrates would look like a pilot's and describe nothing (the lag fit above does)
        dekf: dict[str, float] = {}
    else:
        report_progress("evaluate: identifying with the DEKF")
        dekf = _dekf_identification(whole, model, agent.config)
    element = agent.config.env_kwargs.get("controlled_element", "SI")
    values = reference if reference is not None else reference_pilot(element)
    reference_rms = None
    human = None
    if display is not None and display.shows_error_only:
        if values is not None:
            # the bare task: no limitation wrappers between the pilot and the display
            report_progress("evaluate: flying the typical precision pilot for reference")
            base = gym.make(TASK_IDS[agent.config.task], **{**agent.config.env_kwargs, **overrides})
            reference_recording = fly(Pilot(reference_model(values), dict(values)), base, seed)
            base.close()
            reference_rms = float(np.sqrt(np.mean(reference_recording.e**2)))
        report_progress("evaluate: measuring human-likeness")
        human = human_likeness(recording, reference=reference)
    return Evaluation(
        rms,
        reference_rms,
        response,
        identified,
        dekf,
        tuple(getattr(agent.config, "limitations", agent.config.wrappers)),
        recording,
        human,
        not deterministic,
        agent.config,
        periods,
    )


def _identified_structure(identified: OfflineFit) -> Any:
    """The structure an output-error fit identified (its name says whether it lags)."""
    from manualcontrol.pilots import make_model

    return make_model(identified.model)


def _structure_name(structure: Any) -> str:
    return structure.name + (" (with its lag)" if getattr(structure, "lag", False) else "")


def _fitted_structure(recording: Recording, model: str) -> Any:
    """The structure the output-error fit identifies: on a pure gain, the lag's precision model.

    Humans lag there, and so does the typical pilot the agent is compared with
    (:func:`~manualcontrol.estimators.analysis.human_likeness.reference_pilot`): the rule
    is :func:`~manualcontrol.pilots.models.model_for_element`'s, which ``describe`` and
    ``identify`` follow as well.
    """
    from manualcontrol.pilots.models import make_model, model_for_element

    element = recording.metadata.get("controlled_element")  # the env's, as it ran
    return make_model(model_for_element(model, None if element is None else dict(element)))


def _held_by_rule(recording: Recording, structure: Any) -> dict[str, float]:
    """The output-error fit's held parameters: the lead ``K_v`` at 0 on ``K/s`` and ``K``.

    Humans need no lead on a single integrator; the describing-function fit
    (:func:`~manualcontrol.estimators.analysis.frequency.fit_describing_function`) and
    the filters (``ce="SI"``) hold it at 0 there, and the output-error fit follows the
    same rule, so that the three identify one structure. On a pure gain humans lag,
    with no lead either (the typical pilot there has none).
    """
    from manualcontrol.estimators.members.pilot_rules import element_type

    element = recording.metadata.get("controlled_element")  # the env's, as it ran
    if element is None or "K_v" not in structure.parameter_names:
        return {}
    if element_type(dict(element)) == "SI" or "T_I" in structure.parameter_names:
        return {"K_v": 0.0}
    return {}


def _dekf_identification(recording: Recording, model: str, config: Any) -> dict[str, float]:
    """DEKF estimates averaged over the measurement (t >= 0), the run-in to converge on."""
    from manualcontrol.estimators import DEKF

    element = config.env_kwargs.get("controlled_element", "SI")
    ce = element if element in ("SI", "DI") else None
    settings: dict[str, Any] = {"model": model, "ce": ce}
    if model == "preview":
        settings["anticipation_time"] = float(config.env_kwargs.get("available_preview", 1.0))
    result = DEKF(**settings).estimate(recording)
    measured = np.asarray(recording.t) >= 0.0
    return {name: float(np.mean(result.mean_of(name)[measured])) for name in result.estimated}


def optimal_control_reference(config: Any) -> Any:
    """The OCM pilot on an agent's task, or None where it has none.

    The optimal control model (:class:`~manualcontrol.pilots.OptimalControlPilot`) of the
    agent's element and forcing, with the agent's action delay as its perceptual delay
    where that delay is a constant (0.2 s otherwise) and the model's other values at
    their defaults: the model-based answer to the problem the agent was trained on.
    None on a task other than compensatory tracking or an element the OCM does not take
    (time-varying).
    """
    from manualcontrol.pilots import OptimalControlPilot

    display = TASKS_BY_NAME.get(config.task)  # None on lane keeping
    if display is None or not display.shows_error_only:
        return None
    delay = 0.2
    for spec in getattr(config, "limitations", config.wrappers):
        if spec.get("kind") == "action_delay" and isinstance(spec.get("delay"), (int, float)):
            delay = float(spec["delay"])
    kwargs = config.env_kwargs
    try:
        pilot = OptimalControlPilot(
            kwargs.get("controlled_element", "SI"),
            kwargs.get("forcing", "vanderel-bw4"),
            tau_v=delay,
            disturbance_at=kwargs.get("disturbance_at", "output"),
        )
        pilot.solve()
    except (ValueError, TypeError):
        return None
    return pilot


def _pyplot() -> Any:
    """The pyplot of matplotlib on the file-only Agg backend (reports draw to PNG, headless)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _start_report(evaluation: Any, folder: str | Path) -> tuple[Path, dict[str, Any]]:
    """Create the report folder and write ``evaluation.json``; the folder and the summary."""
    import json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    report_progress(f"evaluate: writing the report and its plots in {folder}")
    summary = evaluation.summary()
    atomic_write(folder / "evaluation.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
    return folder, summary


def write_report(
    evaluation: Evaluation,
    folder: str | Path,
    *,
    models: Mapping[str, Callable[[Any], Any]] | None = None,
) -> Path:
    """Write ``evaluation.md``, ``evaluation.json`` and the plots into ``folder``.

    ``open_loop.png`` (the target lines' open loop) and, on a compensatory task,
    ``human_likeness.png`` (:func:`~manualcontrol.estimators.analysis.human_likeness.
    plot_human_likeness`: measured ``Y_p`` and ``Y_p Y_c``, the crossover model, the
    typical pilot, and each of ``models``: a label and a callable giving a pilot's
    ``Y_p(j omega)`` at frequencies in rad/s, e.g. an OCM pilot's ``frequency_response``).
    """
    plt = _pyplot()
    folder, summary = _start_report(evaluation, folder)
    response = evaluation.frequency_response
    fig, (magnitude, phase) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    magnitude.loglog(response.frequencies, np.abs(response.open_loop), "o-", label="open loop Y/E")
    magnitude.loglog(response.frequencies, np.abs(response.pilot), "s--", label="agent U/E")
    magnitude.axhline(1.0, color="grey", lw=0.8)
    magnitude.set_ylabel("magnitude")
    magnitude.legend()
    phase.semilogx(response.frequencies, np.degrees(np.unwrap(np.angle(response.open_loop))), "o-")
    phase.axhline(-180.0, color="grey", lw=0.8)
    phase.set_ylabel("open-loop phase [deg]")
    phase.set_xlabel("frequency [rad/s]")
    if math.isfinite(response.crossover_frequency):
        for axis in (magnitude, phase):
            axis.axvline(response.crossover_frequency, color="tab:red", lw=0.8)
    magnitude.set_title(
        f"crossover {response.crossover_frequency:.2f} rad/s, "
        f"phase margin {response.phase_margin:.0f} deg"
    )
    fig.tight_layout()
    with atomic_path(folder / "open_loop.png") as temporary:
        fig.savefig(temporary, dpi=110, format="png")
    plt.close(fig)
    human = evaluation.human
    if human is not None:
        if models is None:
            config = evaluation.config
            ocm = None if config is None else optimal_control_reference(config)
            models = {} if ocm is None else {"optimal control model": ocm.frequency_response}
        plot_human_likeness(human, folder / "human_likeness.png", models=models)
    lines = [
        "# Agent evaluation",
        "",
        f"- wrappers' noise: {'on' if evaluation.noise else 'off (deterministic run)'}",
        f"- measured over {evaluation.periods} forcing period(s)",
        f"- RMS tracking error: {summary['rms_error']:.4f}",
    ]
    if summary["reference_rms_error"] is not None:
        lines.append(
            f"- the typical precision-model pilot in the bare task, no noise: "
            f"{summary['reference_rms_error']:.4f} "
            f"(agent / pilot = {summary['bare_task_rms_ratio']:.2f}; "
            "the human-likeness rms_ratio gives that pilot this run's remnant and reads the "
            "run's error about its mean)"
        )
    if summary["implausible"]:
        lines += ["", "**Implausible identifications (do not trust these values):**", ""]
        lines += [f"- {flag}" for flag in summary["implausible"]]
        lines.append("")
    lines += [
        f"- crossover frequency: {summary['crossover_frequency']:.2f} rad/s, "
        f"phase margin {summary['phase_margin']:.1f} deg",
        f"- limitations imposed: {summary['limitations'] or 'none'}",
        "",
        f"Identified {_structure_name(_identified_structure(evaluation.identified))} model "
        "(offline output-error fit, "
        f"VAF {evaluation.identified.vaf:.1f} %):",
        "",
        "| parameter | value |",
        "| --- | --- |",
        *(
            f"| {name} | {value:.4g}"
            + (
                ""
                if name in evaluation.identified.fitted
                else " (held at 0: no lead on this element)"
            )
            + " |"
            for name, value in summary["identified"].items()
        ),
        "",
        *(
            [
                "DEKF (mean of the estimates over the measurement):",
                "",
                "| parameter | value |",
                "| --- | --- |",
                *(f"| {name} | {value:.4g} |" for name, value in summary["dekf"].items()),
            ]
            if summary["dekf"]
            else [
                "DEKF: not run. Its precision model has no lag, and an operator on a pure "
                "gain integrates: its values would describe nothing.",
            ]
        ),
        "",
        "![open loop](open_loop.png)",
        "",
    ]
    if human is not None:
        lines += [
            "## Human-likeness",
            "",
            "```",
            *human.lines(),
            "```",
            "",
            "![human-likeness](human_likeness.png)",
            "",
        ]
    atomic_write(folder / "evaluation.md", lambda p: p.write_text("\n".join(lines)))
    return folder / "evaluation.md"


# ------------------------------------------------------------------- lane keeping

#: Seeds of the roads a lane-keeping agent is evaluated on: random roads no training
#: run starts from (training resets its environments with seeds from 0 up).
LANE_KEEPING_ROADS: tuple[int, ...] = (1000, 1001, 1002, 1003, 1004)


@dataclass(frozen=True)
class LaneKeepingEvaluation:
    """A lane-keeping agent beside the cybernetic driver on the same random roads.

    Per road (``roads``, the seeds of :meth:`~manualcontrol.envs.driving.Road.random`):
    the RMS and largest lateral offset of the agent and of the driver
    (:class:`~manualcontrol.pilots.driver.Driver`, Table 2's values, no remnant) over
    the whole road (the run goes on to the end of the road after a lane departure, so
    every road is scored whole). ``recording`` is the agent's first road.
    """

    roads: tuple[int, ...]
    rms_offset: tuple[float, ...]
    max_offset: tuple[float, ...]
    driver_rms_offset: tuple[float, ...]
    driver_max_offset: tuple[float, ...]
    lane_limit: float
    recording: Recording
    driver_recording: Recording

    @property
    def left_lane(self) -> tuple[bool, ...]:
        """Per road, whether the agent's car left its lane (the env's loss of control)."""
        return tuple(top > self.lane_limit for top in self.max_offset)

    @property
    def rms_ratio(self) -> float:
        """The agent's RMS offset over the driver's, the roads' offsets pooled."""
        agent = math.sqrt(float(np.mean(np.square(self.rms_offset))))
        driver = math.sqrt(float(np.mean(np.square(self.driver_rms_offset))))
        return agent / driver

    def summary(self) -> dict[str, Any]:
        """Plain numbers for tables and JSON."""
        return {
            "task": "lane-keeping",
            "roads": list(self.roads),
            "rms_offset": list(self.rms_offset),
            "max_offset": list(self.max_offset),
            "driver_rms_offset": list(self.driver_rms_offset),
            "driver_max_offset": list(self.driver_max_offset),
            "left_lane": list(self.left_lane),
            "lane_limit": self.lane_limit,
            "rms_ratio": self.rms_ratio,
        }

    def lines(self) -> list[str]:
        """The table printed by ``manualcontrol evaluate``."""
        out = ["road  agent RMS (m)  agent max (m)  driver RMS (m)  driver max (m)  left lane"]
        for road, rms, top, d_rms, d_top, left in zip(
            self.roads,
            self.rms_offset,
            self.max_offset,
            self.driver_rms_offset,
            self.driver_max_offset,
            self.left_lane,
            strict=True,
        ):
            out.append(
                f"{road:4d}  {rms:13.4f}  {top:13.4f}  {d_rms:14.4f}  {d_top:14.4f}  "
                f"{'yes' if left else 'no'}"
            )
        kept = sum(not left for left in self.left_lane)
        out.append(
            f"kept the lane on {kept} of {len(self.roads)} roads (half-width left for the car: "
            f"{self.lane_limit:.2f} m); RMS offset {self.rms_ratio:.2f} times the driver's"
        )
        return out


def evaluate_lane_keeping(
    agent: TrainedAgent,
    *,
    roads: tuple[int, ...] = LANE_KEEPING_ROADS,
    deterministic: bool | None = None,
) -> LaneKeepingEvaluation:
    """Drive the agent and the cybernetic driver over the same random roads, whole.

    The agent drives through its own wrappers (its delay, scales, noise) with
    loss-of-control termination off, so a departure is counted and the road still
    scored to its end; the driver drives the bare task with the agent's steering.
    ``deterministic`` as in :func:`evaluate`: True silences the wrappers' noise; None
    follows the agent's configuration.
    """
    from manualcontrol.pilots.driver import Driver

    if agent.config.task != "lane-keeping":
        raise ValueError(
            f"evaluate_lane_keeping takes a lane-keeping agent, got task {agent.config.task!r}"
        )
    if not roads:
        raise ValueError("roads must name at least one road seed")
    if deterministic is None:
        deterministic = bool(getattr(agent.config, "deterministic", False))
    if deterministic not in (True, False):
        raise TypeError(f"deterministic must be True, False or None, got {deterministic!r}")
    overrides = {"road": "random", "measurement_time": None, "loss_of_control": False}
    steering = agent.config.env_kwargs.get("steering", "torque")
    agents, drivers = [], []
    lane_limit = math.nan
    for road in roads:
        report_progress(f"evaluate: the agent and the driver on random road {road}")
        env = _make_env(agent, not deterministic, overrides)
        agents.append(fly(agent, env, road))
        lane_limit = float(env.unwrapped.lane_limit)
        env.close()
        bare = gym.make(TASK_IDS["lane-keeping"], steering=steering, **overrides)
        drivers.append(fly(Driver(), bare, road))
        bare.close()

    def offsets(recordings: list[Recording]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        values = [np.asarray(recording["y_L"]) for recording in recordings]
        return (
            tuple(float(np.sqrt(np.mean(v**2))) for v in values),
            tuple(float(np.max(np.abs(v))) for v in values),
        )

    return LaneKeepingEvaluation(
        tuple(roads), *offsets(agents), *offsets(drivers), lane_limit, agents[0], drivers[0]
    )


def write_lane_keeping_report(evaluation: LaneKeepingEvaluation, folder: str | Path) -> Path:
    """Write ``evaluation.md``, ``evaluation.json`` and ``lane_offset.png`` into ``folder``."""
    plt = _pyplot()
    folder, _ = _start_report(evaluation, folder)
    fig, axis = plt.subplots(figsize=(8, 3.5))
    for recording, label in (
        (evaluation.recording, "agent"),
        (evaluation.driver_recording, "cybernetic driver"),
    ):
        axis.plot(recording.t, recording["y_L"], lw=0.9, label=label)
    for sign in (1.0, -1.0):
        axis.axhline(sign * evaluation.lane_limit, color="tab:red", lw=0.8)
    axis.set_xlabel("time [s]")
    axis.set_ylabel("lateral offset y_L [m]")
    axis.set_title(f"random road {evaluation.roads[0]}; red: where the car leaves its lane")
    axis.legend(loc="upper right")
    fig.tight_layout()
    with atomic_path(folder / "lane_offset.png") as temporary:
        fig.savefig(temporary, dpi=110, format="png")
    plt.close(fig)
    lines = [
        "# Lane-keeping agent evaluation",
        "",
        "```",
        *evaluation.lines(),
        "```",
        "",
        "![lateral offset](lane_offset.png)",
        "",
    ]
    atomic_write(folder / "evaluation.md", lambda p: p.write_text("\n".join(lines)))
    return folder / "evaluation.md"
