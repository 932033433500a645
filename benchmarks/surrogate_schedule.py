"""A surrogate whose delay rises, tracked by the recommended estimators, beside a pilot model.

The trained agent (``AGENT`` folder) flies its own task with its own limitations, except
that its action delay rises linearly by ``--rise`` seconds over ``--over`` seconds in
the middle of the measurement (the schedule a fatiguing operator might follow). The
RML identifies the run online (filtered) and offline (smoothed), given the element. The
agent's own delay is not known (its policy adds its own dynamics to the imposed delay),
so the score is the tracked *change*: the identified ``tau_v`` minus its median before
the change, against the imposed change, as an NRMSE over the measurement (RMS error
divided by the rise). Beside it, the precision pilot of the same element
(:func:`~manualcontrol.estimators.analysis.human_likeness.reference_pilot`) with the same rise
in its ``tau_v``, simulated with 30 % remnant and identified the same way, scored the
same way and, since its delay is known, also as the NRMSE of ``tau_v`` itself.

Run: .venv/bin/python benchmarks/surrogate_schedule.py AGENT [--rise 0.1 --over 20]
"""

import argparse
import dataclasses
import json

import numpy as np

from manualcontrol.agents.evaluation import fly
from manualcontrol.agents.training import load_agent, make_env
from manualcontrol.envs.schedules import Ramp
from manualcontrol.estimators import RML
from manualcontrol.estimators.analysis.human_likeness import reference_pilot
from manualcontrol.pilots import simulate

RUN_IN = 30.0
MEASUREMENT = 80.0


def _change_scores(result, t_true, change, start):
    """NRMSE of the identified tau_v change (median before ``start`` subtracted)."""
    tau = result.mean[:, result.parameter_names.index("tau_v")]
    t = result.t
    measured = t >= 0.0
    base = np.median(tau[measured & (t < start)])
    imposed = np.interp(t, t_true, change)
    rise = change.max() - change.min()
    return float(np.sqrt(np.mean((tau[measured] - base - imposed[measured]) ** 2)) / rise), tau


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("agent")
    parser.add_argument("--rise", type=float, default=0.1)
    parser.add_argument("--over", type=float, default=20.0)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = parser.parse_args()
    agent = load_agent(args.agent)
    config = agent.config
    element = config.env_kwargs.get("controlled_element", "SI")
    start = 0.5 * (MEASUREMENT - args.over)
    rows = []
    for seed in args.seeds:
        wrappers = []
        for spec in config.wrappers:
            spec = dict(spec)
            if spec["kind"] == "action_delay":
                delay = float(spec["delay"])
                spec["delay"] = Ramp(delay, delay + args.rise, start, start + args.over).to_dict()
            wrappers.append(spec)
        scheduled = dataclasses.replace(config, wrappers=tuple(wrappers))
        env = make_env(
            scheduled,
            measurement_time=MEASUREMENT,
            run_in=RUN_IN,
            realisation=seed,
            loss_of_control=None,
        )
        recording = fly(agent, env, seed, include_run_in=True)
        env.close()
        t_grid = recording.t
        change = np.interp(t_grid, [start, start + args.over], [0.0, args.rise])
        forcing = config.env_kwargs.get("forcing", "vanderel-bw4")
        pilot_values = dict(reference_pilot(element))
        tau0 = pilot_values["tau_v"]
        pilot_values["tau_v"] = Ramp(tau0, tau0 + args.rise, start, start + args.over)
        from manualcontrol.pilots import Pilot

        pilot = Pilot("precision", pilot_values).with_remnant(
            {"kind": "levison", "omega_r": 10.0, "injection": "input", "P_r": 0.3}
        )
        model_run = simulate(
            pilot, element, forcing, realisation=seed, seed=100 + seed, run_in=RUN_IN,
            measurement_time=MEASUREMENT, keep_run_in=True,
        )  # fmt: skip
        for name, smooth in (("rml", False), ("rml-smoothed", True)):
            estimator = RML(model="precision", element=element)
            agent_result = estimator.estimate(recording, smooth=smooth)
            agent_nrmse, _ = _change_scores(agent_result, t_grid, change, start)
            model_result = estimator.estimate(model_run, smooth=smooth)
            model_nrmse, tau = _change_scores(model_result, model_run.t, np.interp(
                model_run.t, [start, start + args.over], [0.0, args.rise]), start)  # fmt: skip
            truth = tau0 + np.interp(model_result.t, [start, start + args.over], [0, args.rise])
            measured = model_result.t >= 0
            absolute = float(
                np.sqrt(np.mean((tau[measured] - truth[measured]) ** 2)) / np.mean(truth[measured])
            )
            rows.append(
                {
                    "seed": seed,
                    "estimator": name,
                    "agent_change_nrmse": round(agent_nrmse, 3),
                    "pilot_change_nrmse": round(model_nrmse, 3),
                    "pilot_tau_v_nrmse": round(absolute, 3),
                }
            )
            print(json.dumps(rows[-1]), flush=True)
    for name in ("rml", "rml-smoothed"):
        mine = [r for r in rows if r["estimator"] == name]
        print(
            f"{name:13s} median change NRMSE: agent "
            f"{np.median([r['agent_change_nrmse'] for r in mine]):.3f}, precision pilot "
            f"{np.median([r['pilot_change_nrmse'] for r in mine]):.3f} (tau_v itself "
            f"{np.median([r['pilot_tau_v_nrmse'] for r in mine]):.3f})"
        )


if __name__ == "__main__":
    main()
