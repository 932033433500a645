"""The human's problem on a pure gain, with the motor noise read the OCM's way: eight trials.

The recipes' motor noise (``agents/recipes.py``) is the OCM's -25 dB read as a share of
the stick's power, and it joins the command ahead of the limb, whose state the policy
reads. The K agents trained on it track better than humans. Each trial here changes
the problem one step further towards the OCM's (Kleinman, Baron & Levison 1970), on
``K`` (recipe ``gain``), and trains and measures it as the recipes are measured:

``ocm-intensity``
    the noise at the OCM's intensity, ``pi rho_u var(command)`` per rad/s
    (:class:`~manualcontrol.agents.wrappers.MotorNoise` ``ratio``), still ahead of the limb;
``after-limb``
    that, joining the stick after the limb (the limb's state no longer shows it);
``held-level``
    the noise after the limb at the OCM's intensity of the typical pilot's stick, a
    level the agent cannot move (``MotorNoise`` ``std``);
``commanded-effort``
    that, with the effort cost on the stick commanded rather than the noisy one
    (:class:`~manualcontrol.agents.wrappers.EffortCost` ``stick="commanded"``), and the
    policy started from the typical pilot's law exactly (``linear_path``);
``limb-unseen``
    the OCM's own posing: the noise at its intensity ahead of the limb, as the OCM adds
    it to the commanded control (``ocm-intensity``), but the limb's state hidden from
    the policy (:class:`~manualcontrol.agents.wrappers.NeuromuscularFilter`
    ``observe_state=False``; the critic still reads it): like the OCM's pilot it knows
    the commands it sent and sees its motor noise only on the display, after the
    delay. Started from the law exactly (``linear_path``);
``limb-unseen-one-frame``
    that, with the policy reading the present frame of the display alone (and its last
    command), at PPO's default learning rate, as the recipes before their memory: with
    no past frames to extrapolate from, can it still answer before its delay?
``limb-unseen-white``
    ``limb-unseen`` with the noise white where it joins the command
    (``MotorNoise`` ``omega_r=None``), at the OCM's intensity: the limb alone shapes
    it, as the OCM's neuromuscular lag shapes its white motor noise. The other trials
    pass it through the 10-rad/s Levison filter first, and the limb shapes it again;
``limb-unseen-white-held``
    that, with the noise's level held at the OCM's intensity of the typical pilot's
    stick (``MotorNoise`` ``std``, white: ``sqrt(pi rho_u / dt)`` times its RMS), as
    the OCM holds its noise intensities while it optimises: a noise scaled to the
    commands can be quietened by commanding less, which the OCM's controller does not
    weigh.

For each trial: the typical pilot's law flown through it (evaluation seed 0, one
period) and its validation return, then each seed's training (the recipe's length and
settings), the return of its warm start and of its kept weights on the validation
episodes, and the kept agent's human-likeness figures. One torch thread per training,
``--jobs`` at a time. Trainings are seeded: a rerun gives the same figures.

The page lists every trial and seed: those not run this time are read from
``<out>/trials.json`` (so ``--seeds 2`` adds a third seed to the trials given).

Run: .venv/bin/python benchmarks/surrogate_noise_trials.py [--trials NAME ...] [--seeds 0 1]
     [--jobs 2] [--out results/surrogate-noise] [--markdown docs/surrogate-noise.md]
"""

import argparse
import dataclasses
import json
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

TRIALS = (
    "ocm-intensity",
    "after-limb",
    "held-level",
    "commanded-effort",
    "limb-unseen",
    "limb-unseen-one-frame",
    "limb-unseen-white",
    "limb-unseen-white-held",
)
#: The trials whose noise joins ahead of the limb, as the OCM adds it to the command.
AHEAD_OF_THE_LIMB = (
    "ocm-intensity",
    "limb-unseen",
    "limb-unseen-one-frame",
    "limb-unseen-white",
    "limb-unseen-white-held",
)
#: The trials that start from the typical pilot's law exactly (``linear_path``).
EXACT_START = ("commanded-effort", *AHEAD_OF_THE_LIMB[1:])
#: The OCM's motor noise ratio (-25 dB) and the recipes' noise break (rad/s).
RHO_U, OMEGA_R = 0.0032, 10.0
#: The recipes' sample time (s).
DT = 0.01


def trial_config(trial: str, seed: int):
    """The ``gain`` recipe's configuration, changed as ``trial`` says (module docstring)."""
    from manualcontrol.agents.recipes import human_problem, typical_stick_rms

    config = human_problem("gain", seed=seed, warm_start="typical-pilot")
    after = trial not in AHEAD_OF_THE_LIMB
    order = ["observation_noise", "action_delay"]
    order += ["motor_noise", "neuromuscular"] if after else ["neuromuscular", "motor_noise"]
    wrappers = []
    for spec in sorted(config.wrappers, key=lambda spec: order.index(spec["kind"])):
        if spec["kind"] == "motor_noise":
            if trial in ("held-level", "commanded-effort"):
                level = math.sqrt(math.pi * RHO_U * OMEGA_R / 2.0) * typical_stick_rms("gain")
                spec = {"kind": "motor_noise", "std": level, "omega_r": OMEGA_R}
            elif trial == "limb-unseen-white-held":  # white: V_u / dt per sample
                level = math.sqrt(math.pi * RHO_U / DT) * typical_stick_rms("gain")
                spec = {"kind": "motor_noise", "std": level, "omega_r": None}
            else:
                white = trial == "limb-unseen-white"
                spec = {
                    "kind": "motor_noise",
                    "ratio": RHO_U,
                    "omega_r": None if white else OMEGA_R,
                }
        if spec["kind"] == "neuromuscular" and trial.startswith("limb-unseen"):
            spec = {**spec, "observe_state": False}
        wrappers.append(spec)
    changes = {"wrappers": tuple(wrappers)}
    if trial == "commanded-effort":
        effort = {"kind": "effort_cost", "rate_weight": config.effort_rate_weight}
        changes["wrappers"] += ({**effort, "stick": "commanded"},)
        changes["effort_rate_weight"] = 0.0
    if trial in EXACT_START:
        changes["policy_kwargs"] = {**config.policy_kwargs, "linear_path": True}
    if trial == "limb-unseen-one-frame":
        changes["history_length"] = 1
        changes["algorithm_kwargs"] = {
            k: v for k, v in config.algorithm_kwargs.items() if k != "learning_rate"
        }
    return dataclasses.replace(config, **changes)


class _LawPolicy:
    """The typical pilot's law where validation asks a policy's ``predict``."""

    def __init__(self, law):
        self.law = law

    def predict(self, batch, deterministic=True):
        del deterministic
        import numpy as np

        return self.law(np.asarray(batch, dtype=np.float64)), None


def _figures(human) -> dict:
    return {
        **{name: round(float(value), 3) for name, value in human.figures().items()},
        "outside": list(human.verdict.outside),
    }


def run_law(trial: str, out: str) -> dict:
    """The typical pilot's law flown through the trial's problem, untrained."""
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.training import (
        TypicalPilotAgent,
        typical_pilot_law,
        validation_score,
    )

    del out
    config = trial_config(trial, 0)
    row = {"trial": trial, "seed": "law"}
    law = typical_pilot_law(config)
    row["validation_return"] = round(validation_score(_LawPolicy(law), config, 20), 1)
    row.update(_figures(evaluate(TypicalPilotAgent(config), seed=0).human))
    return row


def run_training(trial: str, seed: int, out: str) -> dict:
    """One seed of the trial trained as the recipe trains, then measured."""
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate
    from manualcontrol.agents.training import train

    config = trial_config(trial, seed)
    folder = Path(out) / f"{trial}-seed{seed}"
    agent = train(config, folder, report=None)
    selection = json.loads((folder / "selection.json").read_text())
    row = {"trial": trial, "seed": seed}
    row["start_return"] = round(selection["history"][0]["score"], 1)
    row["kept_at"] = selection["kept_step"]
    row["validation_return"] = round(selection["kept_score"], 1)
    row.update(_figures(evaluate(agent, seed=0).human))
    return row


def markdown(rows: list[dict], command: str) -> str:
    """The results page: per trial, the law's row and each seed's."""
    from manualcontrol.estimators.analysis.human_likeness import FIGURES

    lines = [
        "# Surrogates on a pure gain: the motor noise read the OCM's way",
        "",
        f"Generated by `{command}` (trials in its docstring). The recipe `gain`'s",
        "agents track better than humans; each trial poses the motor noise more as the",
        "optimal control model does and trains the recipe on it. `law` is the typical",
        "pilot's equaliser flown through the trial's problem, untrained; `start` the",
        "validation return of the policy PPO starts from (the law cloned), `kept` that of",
        "the weights the recipe keeps (`kept at` their step). Figures are one forcing",
        "period, evaluation seed 0; `*` marks a figure outside the human range.",
        "",
        "| trial | seed | start | kept at | kept | " + " | ".join(FIGURES) + " |",
        "| --- | --- | --- | --- | --- | " + " | ".join("---" for _ in FIGURES) + " |",
    ]
    for row in rows:
        cells = []
        for name in FIGURES:
            value = row[name]
            text = "-" if value != value else f"{value:.3g}"
            cells.append(text + (" *" if name in row["outside"] else ""))
        kept_at = row.get("kept_at")
        lines.append(
            f"| {row['trial']} | {row['seed']} | {row.get('start_return', '-')} | "
            f"{'-' if kept_at is None else f'{kept_at:,}'} | {row['validation_return']} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", nargs="+", choices=TRIALS, default=list(TRIALS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="results/surrogate-noise")
    parser.add_argument("--markdown", default=None, help="write the results page here")
    args = parser.parse_args()
    jobs = [(run_law, (trial, args.out)) for trial in args.trials]
    jobs += [
        (run_training, (trial, seed, args.out)) for trial in args.trials for seed in args.seeds
    ]
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(job, *arguments) for job, arguments in jobs]
        rows = []
        for future in futures:
            rows.append(future.result())
            print(json.dumps(rows[-1]), flush=True)
    kept = Path(args.out) / "trials.json"
    if kept.is_file():  # the rows not run this time (trial and seed), as their last run left them
        run = {(row["trial"], str(row["seed"])) for row in rows}
        rows += [
            row
            for row in json.loads(kept.read_text())
            if (row["trial"], str(row["seed"])) not in run
        ]
    order = {trial: i for i, trial in enumerate(TRIALS)}
    rows.sort(key=lambda row: (order[row["trial"]], str(row["seed"]) != "law", str(row["seed"])))
    Path(args.out).mkdir(parents=True, exist_ok=True)
    kept.write_text(json.dumps(rows, indent=2))
    if args.markdown is not None:
        Path(args.markdown).write_text(markdown(rows, "benchmarks/surrogate_noise_trials.py"))


if __name__ == "__main__":
    main()
