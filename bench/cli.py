"""The ``manualcontrol`` command.

Subcommands: ``simulate`` (a pilot in a tracking task -> a recording), ``identify``
(a recording or an experiment file -> parameter traces and plots), ``bench`` (a suite
-> results table and report), ``suites`` (list them), ``train`` (an RL surrogate
operator) and ``evaluate`` (a trained agent -> report). ``manualcontrol COMMAND
--help`` explains every option.

Exit codes: 0 success; 2 a usage or input error (the message says what to fix, no
traceback); 3 a benchmark finished but some of its runs failed (see the results
table); 1 an unexpected internal error (with traceback).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["main"]

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_RUNS_FAILED = 0, 1, 2, 3


class UsageError(Exception):
    """A mistake of the user: reported as a one-line message, exit code 2."""


def _value(text: str) -> Any:
    """A command-line value: JSON when it parses (numbers, lists, tables), else the string."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _assignments(items: Sequence[str] | None, what: str) -> dict[str, Any]:
    out = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"{what} must look like NAME=VALUE, got {item!r}")
        name, text = item.split("=", 1)
        out[name.strip()] = _value(text)
    return out


def _schedule(text: Any) -> Any:
    """``0.3``, ``sigmoid:0.6,0.3,50,20``, ``sine:0.2,0.05,90,0``, ``ramp:...``, ``step:...``."""
    from manualcontrol.envs.schedules import Ramp, Sigmoid, Sine, Step

    if not isinstance(text, str):
        return text
    kind, _, arguments = text.partition(":")
    builders = {"sigmoid": Sigmoid, "sine": Sine, "ramp": Ramp, "step": Step}
    if kind not in builders or not arguments:
        raise UsageError(
            f"a parameter value must be a number or KIND:ARGS with KIND one of "
            f"{', '.join(builders)}, got {text!r}"
        )
    try:
        return builders[kind](*(float(a) for a in arguments.split(",")))
    except (TypeError, ValueError) as error:
        raise UsageError(f"bad {kind} schedule {text!r}: {error}") from None


# ------------------------------------------------------------------- commands


def _cmd_suites(args: argparse.Namespace) -> int:
    from manualcontrol.bench.scenarios import BUILTIN_SUITES, describe, load_suite

    for name in BUILTIN_SUITES:
        suite = load_suite(name)
        full, quick = suite.scenarios(), suite.scenarios(quick=True)
        print(f"{name}: {suite.description}")
        print(f"    {len(full)} runs ({describe(full)}); --quick: {len(quick)} runs")
    return EXIT_OK


def _cmd_simulate(args: argparse.Namespace) -> int:
    from manualcontrol.pilots import Pilot, simulate

    parameters = {
        name: _schedule(value) for name, value in _assignments(args.param, "--param").items()
    }
    pilot = Pilot(args.model, parameters, remnant=args.remnant, delay_order=args.delay_order)
    recording = simulate(
        pilot,
        args.element,
        args.forcing,
        realisation=args.realisation,
        task=args.task,
        available_preview=args.available_preview,
        dt=args.dt,
        run_in=args.run_in,
        measurement_time=args.measurement_time,
        seed=args.seed,
        loop=args.loop,
    )
    path = recording.save(args.out)
    print(f"wrote {path} ({recording.duration:g} s, {len(recording)} samples)")
    if args.plot:
        from manualcontrol.bench.report import plot_recording

        print(f"wrote {plot_recording(recording, args.plot)}")
    return EXIT_OK


def _cmd_identify(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import plot_estimation
    from manualcontrol.bench.runner import make_estimator
    from manualcontrol.envs._files import atomic_write
    from manualcontrol.envs.recording import Recording

    columns = _assignments(args.column, "--column")
    recording = Recording.load(args.recording, columns=columns or None, dt=args.dt)
    if "e" not in recording and "ft" in recording and "y" in recording:
        recording = recording.with_error_signal()
    settings = _assignments(args.set, "--set")
    estimator = make_estimator({"name": args.estimator, "model": args.model, **settings})
    result = estimator.estimate(recording)
    out = Path(args.out)
    path = result.save(out / "estimation.npz")
    final = {name: round(float(value), 5) for name, value in result.final().items()}
    summary = {
        "final": final,
        "estimated": list(result.estimated),
        "health": result.health.to_dict(),
    }
    atomic_write(out / "summary.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
    figure = plot_estimation(recording, result, out / "parameters.png")
    print(f"estimated {', '.join(result.estimated)}; final values {final}")
    print(f"wrote {path}, {out / 'summary.json'}, {figure}")
    return EXIT_OK if not result.health.diverged else EXIT_RUNS_FAILED


def _cmd_bench(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import write_report
    from manualcontrol.bench.runner import run_suite
    from manualcontrol.bench.scenarios import load_suite

    suite = load_suite(args.suite)
    out = Path(args.out or f"results/{suite.name}{'-quick' if args.quick else ''}")
    total = len(suite.scenarios(args.quick))
    bar = _progress(total, f"{suite.name}", args.quiet)

    def progress(done: int, total: int, row: dict[str, Any]) -> None:
        bar.update(done - bar.n)
        if row.get("status") == "failed":
            bar.write(f"failed: {row['key']}: {row['error']}")

    rows = run_suite(
        suite, out, backend=args.backend, workers=args.workers, quick=args.quick, progress=progress
    )
    bar.close()
    failed = sum(row.get("status") != "ok" for row in rows)
    print(f"results: {out / 'results.csv'} ({len(rows)} runs, {failed} failed)")
    if not args.no_report:
        print(f"report:  {write_report(suite, rows, out)}")
    return EXIT_OK if not failed else EXIT_RUNS_FAILED


def _cmd_train(args: argparse.Namespace) -> int:
    from manualcontrol.agents.training import TrainingConfig, train

    wrappers = []
    if args.delay:
        wrappers.append(
            {"kind": "action_delay", "delay": args.delay, "observe_queue": not args.hide_queue}
        )
    elif args.hide_queue:
        raise UsageError("--hide-queue needs an action delay (--delay SECONDS)")
    if args.neuromuscular:
        omega, zeta = args.neuromuscular
        wrappers.append({"kind": "neuromuscular", "omega_nms": omega, "zeta_nms": zeta})
    if args.motor_noise:
        wrappers.append({"kind": "motor_noise", "power_ratio": args.motor_noise})
    config = TrainingConfig(
        task=args.task,
        env_kwargs=_assignments(args.env, "--env"),
        wrappers=tuple(wrappers),
        algorithm=args.algorithm,
        total_timesteps=args.steps,
        n_envs=args.envs,
        seed=args.seed,
        checkpoint_every=args.checkpoint_every,
        algorithm_kwargs=_assignments(args.algorithm_option, "--algorithm-option"),
        policy_kwargs={} if args.net_arch is None else {"net_arch": list(args.net_arch)},
    )
    agent = train(config, args.out, report=None if args.quiet else print)
    print(f"saved agent to {agent.path} (config.json, policy.pt, model.zip)")
    return EXIT_OK


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from manualcontrol.agents.evaluation import evaluate, write_report
    from manualcontrol.agents.training import load_agent

    agent = load_agent(args.agent, trust_pickle=args.trust_pickle)
    evaluation = evaluate(agent, seed=args.seed)
    path = write_report(evaluation, args.out or Path(args.agent) / "evaluation")
    summary = evaluation.summary()
    print(f"RMS error {summary['rms_error']:.4f}; identified {summary['identified']}")
    print(f"report: {path}")
    return EXIT_OK


def _progress(total: int, description: str, quiet: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=description, unit="run", disable=quiet, file=sys.stderr)


# --------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``manualcontrol`` command."""
    parser = argparse.ArgumentParser(
        prog="manualcontrol",
        description="Tracking tasks, cybernetic pilots and online estimators of manual control.",
        epilog="Exit codes: 0 ok, 2 usage or input error, 3 some benchmark runs failed, "
        "1 internal error.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = commands.add_parser("suites", help="list the built-in benchmark suites")
    p.set_defaults(run=_cmd_suites)

    p = commands.add_parser(
        "simulate", help="simulate a pilot in a tracking task, write a recording"
    )
    p.add_argument(
        "--model",
        default="precision",
        help="pilot model: precision, preview, schiess-roland, gain-delay",
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME=VALUE",
        help="pilot parameter, a number or a schedule like sigmoid:0.6,0.3,50,20 (start, end, "
        "t_mid, transition_time), sine:mean,amplitude,period,phase, ramp:..., step:...; repeatable",
    )
    p.add_argument(
        "--remnant", default=None, help="remnant preset (popovici2017, vertregt2020-SI, ...)"
    )
    p.add_argument(
        "--delay-order",
        type=int,
        default=None,
        help="Padé order of the pilot delay (default exact)",
    )
    p.add_argument(
        "--element", default="SI", help="controlled element preset (SI, DI, popovici2017, ...)"
    )
    p.add_argument("--forcing", default="vanderel-bw4", help="forcing preset")
    p.add_argument("--realisation", type=int, default=0, help="forcing realisation index")
    p.add_argument(
        "--task", default=None, help="compensatory, pursuit or preview (default: the model's)"
    )
    p.add_argument(
        "--available-preview", type=float, default=None, help="preview shown (s), preview tasks"
    )
    p.add_argument("--dt", type=float, default=0.01, help="sample time (s)")
    p.add_argument("--run-in", type=float, default=60.0, help="run-in simulated and cut (s)")
    p.add_argument(
        "--measurement-time", type=float, default=None, help="measured time (s), default T_m"
    )
    p.add_argument("--seed", type=int, default=0, help="remnant seed")
    p.add_argument("--loop", default="continuous", help="continuous or sampled")
    p.add_argument("--out", required=True, type=Path, help="recording file (.npz, .csv or .mat)")
    p.add_argument("--plot", type=Path, default=None, help="also draw the run to this PNG")
    p.set_defaults(run=_cmd_simulate)

    p = commands.add_parser(
        "identify", help="estimate pilot parameters from a recording or experiment file"
    )
    p.add_argument(
        "recording", type=Path, help="a Recording or an experiment file (.npz, .csv, .mat)"
    )
    p.add_argument("--estimator", default="dekf", help="estimator name (default dekf)")
    p.add_argument(
        "--model", default="precision", help="pilot model structure: precision or preview"
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="estimator setting, e.g. ce=DI, anticipation_time=0.9, r2=4, "
        'estimated=["K_p","K_v"]; repeatable',
    )
    p.add_argument(
        "--column",
        action="append",
        metavar="SIGNAL=COLUMN",
        help="map a file column to a signal, e.g. u=stick; repeatable",
    )
    p.add_argument(
        "--dt", type=float, default=None, help="sample time when the file has no time column"
    )
    p.add_argument("--out", type=Path, default=Path("results/identify"), help="output folder")
    p.set_defaults(run=_cmd_identify)

    p = commands.add_parser("bench", help="run a benchmark suite, write results and a report")
    p.add_argument("suite", help="built-in suite name (see `manualcontrol suites`) or a .toml file")
    p.add_argument("--out", type=Path, default=None, help="output folder (default results/SUITE)")
    p.add_argument("--quick", action="store_true", help="each batch's quick subset")
    p.add_argument(
        "--backend",
        default="process",
        choices=("process", "inprocess", "ray"),
        help="process pool (default), in this process, or Ray",
    )
    p.add_argument(
        "--workers", type=int, default=None, help="process-pool size (default: all cores)"
    )
    p.add_argument("--no-report", action="store_true", help="skip the Markdown/PNG report")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_cmd_bench)

    p = commands.add_parser("train", help="train an RL surrogate operator (stable-baselines3)")
    p.add_argument(
        "--task", default="compensatory", help="compensatory, pursuit, preview or lane-keeping"
    )
    p.add_argument(
        "--env",
        action="append",
        metavar="KEY=VALUE",
        help="environment keyword, e.g. controlled_element=DI; repeatable",
    )
    p.add_argument("--delay", type=float, default=0.0, help="action delay (s)")
    p.add_argument(
        "--hide-queue",
        action="store_true",
        help="hide the actions still in the delay queue from the agent (by default they "
        "are observed, which keeps the task Markov but lets the agent predict through "
        "the delay; hidden, it must act through the delay as a human does)",
    )
    p.add_argument(
        "--neuromuscular",
        type=float,
        nargs=2,
        metavar=("OMEGA", "ZETA"),
        default=None,
        help="neuromuscular filter frequency (rad/s) and damping",
    )
    p.add_argument(
        "--motor-noise", type=float, default=None, metavar="P_R", help="motor-noise power ratio"
    )
    p.add_argument("--algorithm", default="sac", choices=("sac", "ppo"), help="RL algorithm")
    p.add_argument("--steps", type=int, default=100_000, help="environment steps")
    p.add_argument("--envs", type=int, default=1, help="parallel environments")
    p.add_argument(
        "--algorithm-option",
        action="append",
        metavar="KEY=VALUE",
        help="keyword for the stable-baselines3 algorithm, e.g. n_steps=512; repeatable",
    )
    p.add_argument(
        "--net-arch",
        type=int,
        nargs="+",
        metavar="UNITS",
        default=None,
        help="hidden layer sizes of the policy (and value) networks, e.g. 64 64",
    )
    p.add_argument("--seed", type=int, default=0, help="seed")
    p.add_argument("--checkpoint-every", type=int, default=None, help="save weights every N steps")
    p.add_argument("--out", type=Path, required=True, help="output folder for the agent")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(run=_cmd_train)

    p = commands.add_parser("evaluate", help="evaluate a trained agent like a human operator")
    p.add_argument("agent", type=Path, help="folder written by `manualcontrol train`")
    p.add_argument(
        "--out", type=Path, default=None, help="report folder (default AGENT/evaluation)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation run")
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load model.zip (pickle: runs code from the file; only for files you trust)",
    )
    p.set_defaults(run=_cmd_evaluate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; return its exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (UsageError, ValueError, TypeError, KeyError, FileNotFoundError) as error:
        # our checks raise these for bad input; MANUALCONTROL_DEBUG=1 shows the traceback
        if os.environ.get("MANUALCONTROL_DEBUG"):
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"manualcontrol {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USAGE


def main_exit() -> None:
    """Console-script entry point: run and exit with the command's code."""
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    main_exit()
