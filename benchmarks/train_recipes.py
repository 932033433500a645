"""Train the human's problem on each element, and the lane-keeping recipes; measure each agent.

Tracking (:func:`manualcontrol.agents.recipes.human_problem`, the recipes'
configuration; ``1/s`` is recipe ``si``): for each element and seed, the training time,
the mean return over held-out episodes (:func:`held_out_return`, beside the typical
pilot's equaliser's on the same episodes), then
:func:`~manualcontrol.agents.evaluation.evaluate` (the wrappers' noise on,
evaluation seed 0, one full forcing period) and its human-likeness figures and verdict,
beside the optimal control model's optimum on the same problem.

Lane keeping (recipes ``lane-angle`` and ``lane-torque``): for each seed, the training
time, then :func:`~manualcontrol.agents.evaluation.evaluate_lane_keeping` (five random
roads no training run starts from, each beside the cybernetic driver).

``--jobs 2`` trains two agents at a time with one torch thread each (each then has one
of the two cores: its training time is an upper bound on the time with both).

Elements in ``--warm-start`` (default: all four, as the recipes ``gain``, ``si``, ``di``
and ``lag`` do) start from the typical pilot's equaliser.

Run: .venv/bin/python benchmarks/train_recipes.py [--elements gain 1/s 1/s^2 "1/(s(s+1))"]
     [--lane-keeping angle torque] [--seeds 0 1 2]
     [--jobs 2] [--out results/recipes] [--markdown docs/surrogates.md] [--steps N]
     [--periods N] [--existing] [--variant recipe|final|one-frame|display-critic]

``--periods N`` evaluates each tracking agent over N forcing periods read together (a
laboratory's average over repeated runs); ``--existing`` re-evaluates the tracking agents
already in ``--out`` without training them again. ``--variant`` trains (or re-evaluates)
the tracking agents in an earlier form of the recipes (:func:`variant_config`);
``--existing --variant final`` re-evaluates the recipes' trainings with their last weights.

``--markdown`` writes the tables as a results page; ``--table results/recipes/recipes.json``
writes it from an earlier run's figures without training.
"""

import argparse
import dataclasses
import json
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

#: Held-out episodes each tracking agent's return is measured on.
RETURN_EPISODES = 16


def held_out_return(actor, config) -> float:
    """Mean undiscounted return of ``actor.act`` over :data:`RETURN_EPISODES` episodes.

    The quantity the agents train on, through the configuration's own wrappers (noise
    on), from the validation seeds no training run starts from
    (:data:`~manualcontrol.agents.training.VALIDATION_SEED` up): the agents and the
    typical pilot's equaliser on the same episodes, so their returns compare pairwise.
    Not :func:`~manualcontrol.agents.training.validation_score`, which flies a policy's
    batched ``predict`` on float32 observations: the law acts on the display as it is.
    """
    from manualcontrol.agents.training import VALIDATION_SEED, make_env

    returns = []
    for i in range(RETURN_EPISODES):
        env = make_env(config)
        observation, _ = env.reset(seed=VALIDATION_SEED + i)
        total, done = 0.0, False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(actor.act(observation))
            total += float(reward)
            done = terminated or truncated
        env.close()
        returns.append(total)
    return sum(returns) / len(returns)


#: The forms of the human's problem a tracking job trains: the recipes' own, and the
#: earlier forms the results page compares them with (``--variant``). ``final`` is the
#: recipe's own training with the weights it ended with instead of the kept ones (the
#: recipes before they kept their best validated weights): it is only re-evaluated.
VARIANTS = ("recipe", "final", "one-frame", "display-critic")


def variant_config(config, variant: str):
    """``config`` (the recipe's) in the form ``variant`` (:data:`VARIANTS`).

    ``one-frame``: the policy reads the present frame only, at PPO's default learning
    rate (the recipes before their memory); ``display-critic``: that, with a critic
    that reads only the display too (the recipes before their informed critic).
    """
    if variant in ("recipe", "final"):
        return config
    from manualcontrol.agents.training import VALIDATION_SEED

    options = {k: v for k, v in config.algorithm_kwargs.items() if k != "learning_rate"}
    # the earlier forms kept their last weights: no selection, its seed the default, so
    # each form equals the configuration its agents were trained with (their config.json)
    config = dataclasses.replace(
        config,
        history_length=1,
        algorithm_kwargs=options,
        select_every=None,
        select_seed=VALIDATION_SEED,
    )
    if variant == "display-critic":
        config = dataclasses.replace(config, critic_information=False)
    return config


def run_tracking(
    element: str,
    seed: int,
    out: str,
    steps: int | None,
    warm: bool,
    periods: int,
    existing: bool,
    *,
    variant: str = "recipe",
) -> dict:
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate, optimal_control_reference
    from manualcontrol.agents.recipes import human_problem
    from manualcontrol.agents.training import load_agent, train

    config = human_problem(
        element,
        seed=seed,
        warm_start="typical-pilot" if warm else "none",
        **({} if steps is None else {"total_timesteps": steps}),
    )
    config = variant_config(config, variant)
    folder = element.replace("/", "_").replace("(", "").replace(")", "").replace("^", "")
    folder += "-warm" if warm else ""
    folder += "" if variant in ("recipe", "final") else f"-{variant}"
    folder = Path(out) / f"{folder}-seed{seed}"
    start = time.perf_counter()
    if existing:
        agent = load_agent(folder)
        train_s = "-"
    elif variant == "final":
        raise ValueError("--variant final re-evaluates the recipe's training: give --existing")
    else:
        agent = train(config, folder, report=None)
        train_s = round(time.perf_counter() - start)
    row = {"element": element, "seed": seed, "train_s": train_s, "periods": periods}
    if variant == "final":
        agent.policy.load_state_dict(torch.load(folder / "policy_final.pt", weights_only=True))
        row["weights"] = "final"
    elif (folder / "selection.json").is_file():
        row["weights"] = json.loads((folder / "selection.json").read_text())["kept_step"]
    row["start"] = config.warm_start
    row["critic"] = "informed" if config.critic_information else "display"
    row["memory"] = config.history_length
    row["return"] = round(held_out_return(agent, config), 1)
    human = evaluate(agent, seed=0, periods=periods).human
    row.update({k: round(float(v), 3) for k, v in human.figures().items()})
    row["outside"] = list(human.verdict.outside)
    crossover, margin, delay = optimal_control_reference(config).crossover()
    row["ocm"] = [round(crossover, 2), round(margin, 1), round(delay, 3)]
    return row


def run_law(
    element: str, seed: int, out: str, steps: int | None, warm: bool, periods: int, existing: bool
) -> dict:
    """The typical pilot's equaliser itself, flown through the problem's wrappers, untrained.

    What the warm start begins from, measured as an agent is: the figures the problem's
    noise alone gives the typical pilot's loop.
    """
    from manualcontrol.agents.evaluation import evaluate, optimal_control_reference
    from manualcontrol.agents.recipes import human_problem
    from manualcontrol.agents.training import TypicalPilotAgent

    del seed, out, steps, warm, existing
    config = human_problem(element, warm_start="typical-pilot")
    human = evaluate(TypicalPilotAgent(config), seed=0, periods=periods).human
    row = {"element": element, "seed": "-", "train_s": "-", "start": "law, untrained"}
    row["periods"] = periods
    row["return"] = round(held_out_return(TypicalPilotAgent(config), config), 1)
    row.update({k: round(float(v), 3) for k, v in human.figures().items()})
    row["outside"] = list(human.verdict.outside)
    crossover, margin, delay = optimal_control_reference(config).crossover()
    row["ocm"] = [round(crossover, 2), round(margin, 1), round(delay, 3)]
    return row


def run_lane_keeping(
    steering: str, seed: int, out: str, steps: int | None, warm: bool, periods: int, existing: bool
) -> dict:
    import torch

    torch.set_num_threads(1)
    from manualcontrol.agents.evaluation import evaluate_lane_keeping
    from manualcontrol.agents.recipes import lane_keeping_problem
    from manualcontrol.agents.training import train

    config = lane_keeping_problem(
        steering, seed=seed, **({} if steps is None else {"total_timesteps": steps})
    )
    start = time.perf_counter()
    agent = train(config, Path(out) / f"lane-{steering}-seed{seed}", report=None)
    row = {"steering": steering, "seed": seed, "train_s": round(time.perf_counter() - start)}
    row["steps"] = config.total_timesteps
    summary = evaluate_lane_keeping(agent).summary()
    row["roads_kept"] = sum(not left for left in summary["left_lane"])
    row["roads"] = len(summary["roads"])
    row["rms_offset"] = round(max(summary["rms_offset"]), 4)
    row["max_offset"] = round(max(summary["max_offset"]), 4)
    row["driver_rms_offset"] = round(max(summary["driver_rms_offset"]), 4)
    row["rms_ratio"] = round(summary["rms_ratio"], 3)
    final = Path(out) / f"lane-{steering}-seed{seed}" / "policy_final.pt"
    if final.is_file():  # the weights training ended with, beside the kept ones
        selection = json.loads(final.with_name("selection.json").read_text())
        row["kept_step"] = selection["kept_step"]
        agent.policy.load_state_dict(torch.load(final, weights_only=True))
        summary = evaluate_lane_keeping(agent).summary()
        row["final_roads_kept"] = sum(not left for left in summary["left_lane"])
        row["final_rms_ratio"] = round(summary["rms_ratio"], 3)
    return row


def _count(value: int | None) -> str:
    """A step count with thousands separators; '-' where a row has none."""
    return "-" if value is None else f"{value:,}"


def markdown(rows: list[dict], command: str) -> str:
    """The results page: one line per agent, each figure beside the human range."""
    from manualcontrol.estimators.analysis.human_likeness import FIGURES

    tracking = [row for row in rows if "element" in row]
    elements = list(dict.fromkeys(row["element"] for row in tracking))
    tracking.sort(
        key=lambda row: (
            elements.index(row["element"]),
            ["law, untrained", "none", "typical-pilot"].index(row.get("start", "none")),
            row.get("critic", "informed") != "display",
            row.get("memory", 1),
            str(row["seed"]),
            row.get("weights") == "final",
            row.get("periods", 1),
        )
    )
    lanes = [row for row in rows if "steering" in row]
    periods = sorted({row.get("periods", 1) for row in tracking})
    span = " or ".join(str(n) for n in periods)
    span = "one forcing period" if periods == [1] else f"{span} forcing periods"
    lines = [
        "# Surrogate operators: what the human's problem trains",
        "",
        f"Generated by `{command}`.",
        "",
        "## Compensatory tracking",
        "",
        "The human's problem (`agents/recipes.py`, `human_problem`; the recipes `gain`,",
        "`si`, `di` and `lag` are it on K, 1/s, 1/s^2 and 1/(s(s+1)) with start",
        "`typical-pilot`; on K the policy also reads its own last command)",
        "trained on each element with each seed (one torch thread per training, two",
        f"at a time on two cores), then evaluated over {span} with the",
        "wrappers' noise on (`manualcontrol evaluate --periods`; several periods are",
        "read together, as a laboratory averages a participant's repeated runs; the",
        "same trained agents in both). A figure outside the human range of",
        "`manualcontrol.estimators.analysis.human_likeness` is marked `*`. `OCM` is the",
        "optimal control model's optimum on the same problem (crossover rad/s, phase",
        "margin deg, effective delay s): what the agent would become if it learned the",
        "problem's optimum.",
        "",
        "`start` is `none` for PPO from its random policy, `typical-pilot` for PPO",
        "started from the typical pilot's equaliser (`warm_start`; every tracking",
        "recipe); `law, untrained` is that equaliser itself flown through the same",
        "wrappers, no training: what the problem's noise alone makes of the typical",
        "pilot's loop.",
        "",
        "PPO's critic reads the loop's hidden state as well (`critic_information`: the",
        "forcing ahead, the element's state, the delayed commands, the noise's state);",
        "the policy, which acts and is measured, reads only the display: its last",
        "`memory` frames (`history_length`; the recipes' 20 frames are 0.2 s). `return`",
        f"is what training maximises: the mean return of {RETURN_EPISODES} held-out",
        "episodes (the same for every row of an element; noise on, one period), so an",
        "agent whose return is above its law's did better than the typical pilot's",
        "equaliser on its own objective. The same seeds trained as the recipes did",
        "before stand beside them: `memory` 1, the present frame only, at PPO's",
        "default learning rate (`--variant one-frame`), and that with critic",
        "`display`, a critic that reads only the display (`--variant display-critic`).",
        "",
        "`weights`: the recipes keep the best of the weights validated every",
        "200,000 steps on 20 episodes apart from the held-out ones, the start's",
        "among them (`select_every`; `kept at` the step they are from, 0 the warm",
        "start itself); `final` is the same training's last weights (the recipes",
        "before they kept their best: the same training, so the same weights); `-`:",
        "the earlier forms, which kept their last weights.",
        "",
        "| element | start | critic | memory | weights | seed | train (s) | periods | return | "
        + " | ".join(FIGURES)
        + " | OCM |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | "
        + " | ".join("---" for _ in FIGURES)
        + " | --- |",
    ]
    for row in tracking:
        cells = []
        for name in FIGURES:
            value = row.get(name)
            text = "-" if value is None or value != value else f"{value:.3g}"
            cells.append(text + (" *" if name in row["outside"] else ""))
        ocm = " / ".join(f"{v:g}" for v in row.get("ocm", [])) or "-"
        weights = row.get("weights", "-")
        weights = f"kept at {weights:,}" if isinstance(weights, int) else weights
        lines.append(
            f"| {row['element']} | {row.get('start', 'none')} | {row.get('critic', '-')} | "
            f"{row.get('memory', '-')} | {weights} | {row['seed']} | "
            f"{row['train_s']} | {row.get('periods', 1)} | {row.get('return', '-')} | "
            + " | ".join(cells)
            + f" | {ocm} |"
        )
    if lanes:
        lines += [
            "",
            "## Lane keeping",
            "",
            "The recipes `lane-angle` and `lane-torque` (`lane_keeping_problem`), each seed",
            "evaluated on five random roads no training run starts from, beside the",
            "cybernetic driver on the same roads (`manualcontrol evaluate`). Offsets are",
            "the largest over the roads; the ratio pools the roads' RMS offsets. The",
            "weights evaluated are those the recipe keeps, the best of its validations",
            "(`select_every`; `kept at`: the training step they are from); `final` is the",
            "same training's last weights on the same roads (roads kept, RMS / driver's).",
            "",
            "| steering | seed | train (s) | steps | kept at | roads kept | RMS offset (m) "
            "| max offset (m) | driver RMS (m) | RMS / driver's | final |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for row in lanes:
            final = (
                f"{row['final_roads_kept']} of {row['roads']}, {row['final_rms_ratio']:.3g}"
                if "final_roads_kept" in row
                else "-"
            )
            lines.append(
                f"| {row['steering']} | {row['seed']} | {row['train_s']} | "
                f"{_count(row.get('steps'))} | {_count(row.get('kept_step'))} | "
                f"{row['roads_kept']} of {row['roads']} | {row['rms_offset']:.4f} | "
                f"{row['max_offset']:.4f} | {row['driver_rms_offset']:.4f} | "
                f"{row['rms_ratio']:.3g} | {final} |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", nargs="*", default=["gain", "1/s", "1/(s(s+1))", "1/s^2"])
    parser.add_argument("--lane-keeping", nargs="*", default=["angle", "torque"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--steps", type=int, default=None, help="training length (a quick check)")
    parser.add_argument("--out", default="results/recipes")
    parser.add_argument("--markdown", default=None, help="write the results page here")
    parser.add_argument(
        "--warm-start",
        nargs="*",
        default=["gain", "1/s", "1/(s(s+1))", "1/s^2"],
        help="elements trained from the typical pilot's equaliser (the recipes gain, si, di, lag)",
    )
    parser.add_argument(
        "--laws",
        nargs="*",
        default=["gain", "1/s", "1/(s(s+1))", "1/s^2"],
        help="elements whose typical pilot's equaliser is measured untrained beside them",
    )
    parser.add_argument(
        "--table", nargs="+", default=None, help="recipes.json of earlier runs (joined)"
    )
    parser.add_argument(
        "--periods",
        type=int,
        default=1,
        help="forcing periods each tracking evaluation flies and measures over",
    )
    parser.add_argument(
        "--variant",
        choices=VARIANTS,
        default="recipe",
        help="train (or, with --existing, evaluate) the tracking agents as the recipes "
        "do, or as they did before: one-frame (no memory, PPO's default learning rate), "
        "display-critic (that, and a critic that reads only the display); the "
        "comparisons the results page shows",
    )
    parser.add_argument(
        "--existing",
        action="store_true",
        help="evaluate the tracking agents already trained in --out instead of training; "
        "their training times are taken from --out's recipes.json",
    )
    args = parser.parse_args()
    command = "benchmarks/train_recipes.py"
    if args.table is not None:
        rows = [row for table in args.table for row in json.loads(Path(table).read_text())]
        Path(args.markdown).write_text(markdown(rows, command))
        return
    jobs = [
        (run_tracking, element, seed, element in args.warm_start)
        for element in args.elements
        for seed in args.seeds
    ]
    if args.variant != "recipe":
        jobs = [(partial(run_tracking, variant=args.variant), *job[1:]) for job in jobs]
    jobs += [(run_law, element, 0, False) for element in args.laws]
    if not args.existing:  # lane-keeping agents are trained, never re-read
        jobs += [
            (run_lane_keeping, steering, seed, False)
            for steering in args.lane_keeping
            for seed in args.seeds
        ]
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [
            pool.submit(job, name, seed, args.out, args.steps, warm, args.periods, args.existing)
            for job, name, seed, warm in jobs
        ]
        for future in futures:
            rows.append(future.result())
            print(json.dumps(rows[-1]), flush=True)
    table = Path(args.out) / "recipes.json"
    if args.existing:  # the training run's own table stays as it was written
        if table.exists():
            earlier = json.loads(table.read_text())
            trained = {(r.get("element"), r["seed"]): r["train_s"] for r in earlier}
            for row in rows:
                if row.get("train_s") == "-" and (row.get("element"), row["seed"]) in trained:
                    row["train_s"] = trained[row.get("element"), row["seed"]]
        form = "" if args.variant == "recipe" else f"-{args.variant}"
        table = Path(args.out) / f"recipes{form}-periods{args.periods}.json"
    Path(args.out).mkdir(parents=True, exist_ok=True)
    table.write_text(json.dumps(rows, indent=2))
    if args.markdown is not None:
        Path(args.markdown).write_text(markdown(rows, command))


if __name__ == "__main__":
    main()
