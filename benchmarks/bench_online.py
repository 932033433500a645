"""Online loop cost per step: env, pilot, wrappers, observer and the DEKF's update().

One hour at 100 Hz is 360,000 steps; "1,000x real time" is 10 us a step. Timed here,
per step, medians of REPEATS episodes of STEPS steps in one process (CPU time of this
process, so other load on the machine counts less), after one warm-up episode, the
loops taking turns episode by episode so that a drift in the machine's load falls on all:

- env: ``CompensatoryTracking-v0`` / ``PreviewTracking-v0`` (DI) stepped with a fixed
  action, through ``gymnasium.make`` (its default wrappers included);
- env + pilot: a cybernetic pilot acting (``pilot.act`` then ``env.step``);
- wrappers: ActionDelay (0.125 s, queue observed), MotorNoise (30 %) and
  NeuromuscularFilter each around the env, the pilot acting;
- env + pilot + observer: ``EstimatorObserver`` with a causal DEKF around the env,
  reporting dicts each step (the default), arrays, or nothing (``estimates_in_info``);
- the same observer with a causal RML (input remnant), dicts and nothing, beside the
  RML's own cost per sample inside ``estimate()``;
- DEKF.update alone, fed the samples of a recorded episode, beside ``estimate()`` of
  the same recording per sample: the issue asks ``update`` within 2x of that; and
  ``update_plain`` (what the observer's dicts form calls: one C call where the C ports
  and the online extension build);
- the observer's own cost: env + pilot + observer less env + pilot and less the
  DEKF's cost per sample inside ``estimate()`` (the target: at most 0.5x that cost);
- what ``update`` is made of: the compiled one-sample step called through the entry
  point ``update`` uses (its records unboxed on every call; the inputs of each sample
  a row view of a prepared table), and the check of the sample dict alone; the rest
  of ``update`` is Python around them (the time, the ``Estimate``).

Run: .venv/bin/python benchmarks/bench_online.py [--steps N] [--repeats N]
Old code, for a side-by-side run: PYTHONPATH=<old tree mapped as manualcontrol>.
"""

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401
from manualcontrol.agents.wrappers import ActionDelay, MotorNoise, NeuromuscularFilter
from manualcontrol.estimators import DEKF, RML
from manualcontrol.estimators.observer import EstimatorObserver
from manualcontrol.estimators.protocol import sample_floats
from manualcontrol.pilots import Pilot

DI = dict(K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3)
PREVIEW_DI = dict(K_f=0.9, omega_f=1.0, **DI)
TASKS = {
    "compensatory": (
        "Compensatory",
        lambda: Pilot("precision", DI),
        dict(model="precision", ce="DI", initial_variance="causal", initial={"K_p": 0.24}),
    ),
    "preview": (
        "Preview",
        lambda: Pilot("preview", PREVIEW_DI),
        dict(
            model="preview",
            ce="DI",
            anticipation_time=0.9,
            initial_variance="causal",
            initial={"K_p": 0.24},
        ),
    ),
}


def make_env(task, steps):
    return gym.make(
        f"ManualControl/{TASKS[task][0]}Tracking-v0",
        controlled_element="DI",
        run_in=0.0,
        measurement_time=steps * 0.01,
    )


def episode(env, pilot, steps, width=None):
    """CPU seconds of one episode of ``steps`` steps (pilot acting, or a fixed action)."""
    observation, _ = env.reset(seed=0)
    if pilot is not None:
        pilot.reset(seed=1, env=env)
    action = np.array([0.1])
    start = time.process_time()
    for _ in range(steps):
        if pilot is not None:
            action = pilot.act(observation if width is None else observation[:width])
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    return time.process_time() - start


def summary(times, count):
    """Median and minimum per item: on a shared machine the minimum is the quiet cost."""
    return statistics.median(times) / count, min(times) / count


def per_step(make, pilot_factory, steps, repeats, width=None):
    """A loop ready to time: its env, pilot and width, warmed up (kernels compiled or loaded)."""
    del repeats  # timed by measured_together, the loops taking turns
    env = make()
    pilot = None if pilot_factory is None else pilot_factory()
    episode(env, pilot, min(steps, 200), width)
    return env, pilot, width


def measured_together(loops, steps, repeats):
    """Per-step medians and minima of every loop, the loops taking turns episode by episode.

    On a shared machine the load drifts over minutes; timing each loop's episodes one
    after another would hand one loop a busy minute and the next a quiet one, and the
    ratios between loops would measure the drift.
    """
    times = {name: [] for name in loops}
    for _ in range(repeats):
        for name, (env, pilot, width) in loops.items():
            times[name].append(episode(env, pilot, steps, width))
    return {name: summary(values, steps) for name, values in times.items()}


def recorded_episode(task, steps):
    """An episode of the task's pilot, recorded (the samples the observer would feed)."""
    _, pilot_factory, _ = TASKS[task]
    env = make_env(task, steps)
    pilot = pilot_factory()
    observation, _ = env.reset(seed=0)
    pilot.reset(seed=1, env=env)
    for _ in range(steps):
        observation, *_ = env.step(pilot.act(observation))
    return env.unwrapped.recording(include_run_in=True)


def estimate_cost(task, estimator, steps, repeats):
    """Per-sample CPU of ``estimator.estimate()`` on a recorded episode."""
    recording = recorded_episode(task, steps)

    def run():
        start = time.process_time()
        estimator.estimate(recording)
        return time.process_time() - start

    run()
    return summary([run() for _ in range(repeats)], len(recording))


def dekf_costs(task, steps, repeats):
    """Per-sample CPU of DEKF.update over a recorded episode and of estimate()."""
    settings = TASKS[task][2]
    recording = recorded_episode(task, steps)
    estimator = DEKF(**settings)
    samples = estimator.signals(recording)
    keys = estimator.sample_keys
    table = [
        {**{key: float(samples[key][k]) for key in keys}, "t": float(recording.t[k])}
        for k in range(len(recording))
    ]

    def updates(name):
        def run():
            estimator.reset(recording.dt, t0=float(recording.t[0]))
            update = getattr(estimator, name)
            start = time.process_time()
            for sample in table:
                update(sample)
            return time.process_time() - start

        return run

    def run_estimate():
        start = time.process_time()
        estimator.estimate(recording)
        return time.process_time() - start

    inputs = np.column_stack([samples[name] for name in estimator._internal.input_names])
    u, e = np.asarray(samples["u"], dtype=np.float64), np.asarray(samples["e"], dtype=np.float64)

    def run_compiled_step():
        estimator.reset(recording.dt, t0=float(recording.t[0]))
        estimator.update(table[0])  # finds the compiled overload, as update does
        entry, records, row = estimator._entry, estimator._records, estimator._row
        start = time.process_time()
        for k in range(1, len(table)):
            entry(*records, inputs[k], u[k], e[k], 0, row)
        return time.process_time() - start

    where, allowed = estimator._where, estimator._allowed_sample_keys

    def run_sample_check():
        start = time.process_time()
        for sample in table:
            sample_floats(where, sample, keys, allowed)
        return time.process_time() - start

    costs = {}
    for name, run in (
        ("DEKF.update alone", updates("update")),
        ("DEKF.update_plain alone", updates("update_plain")),
        ("DEKF.estimate, per sample", run_estimate),
        ("  its compiled step, entry alone", run_compiled_step),
        ("  its sample check alone", run_sample_check),
    ):
        run()
        costs[name] = summary([run() for _ in range(repeats)], len(table))
    return costs


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    steps, repeats = args.steps, args.repeats
    print(f"CPU time per step (us): median and minimum of {repeats} episodes of {steps} steps")
    for task, (_, pilot_factory, settings) in TASKS.items():
        width = make_env(task, 10).observation_space.shape[0]
        rows = {
            "env": per_step(lambda t=task: make_env(t, steps), None, steps, repeats),
            "env + pilot": per_step(
                lambda t=task: make_env(t, steps), pilot_factory, steps, repeats
            ),
            "env + pilot + ActionDelay": per_step(
                lambda t=task: ActionDelay(make_env(t, steps), 0.125),
                pilot_factory,
                steps,
                repeats,
                width,
            ),
            "env + pilot + MotorNoise": per_step(
                lambda t=task: MotorNoise(make_env(t, steps), 0.3), pilot_factory, steps, repeats
            ),
            "env + pilot + NeuromuscularFilter": per_step(
                lambda t=task: NeuromuscularFilter(make_env(t, steps)),
                pilot_factory,
                steps,
                repeats,
                width,
            ),
            "env + pilot + observer(DEKF)": per_step(
                lambda t=task, s=settings: EstimatorObserver(make_env(t, steps), DEKF(**s)),
                pilot_factory,
                steps,
                repeats,
            ),
        }
        # the thin path (no per-step dicts) with the DEKF; the RML (a bank of filters,
        # several times the DEKF's arithmetic a sample), causal, both ways
        rml = {**settings, "remnant_injection": "input"}
        for member, member_settings, forms in (
            (DEKF, settings, ("arrays", "none")),
            (RML, rml, ("dicts", "none")),
        ):
            for form in forms:
                rows[f"env + pilot + observer({member.__name__}), {form}"] = per_step(
                    lambda t=task, m=member, s=member_settings, f=form: EstimatorObserver(
                        make_env(t, steps), m(**s), estimates_in_info=f
                    ),
                    pilot_factory,
                    steps,
                    repeats,
                )
        rows = measured_together(rows, steps, repeats)
        rows["RML.estimate, per sample"] = estimate_cost(task, RML(**rml), steps, repeats)
        costs = dekf_costs(task, steps, repeats)
        rows.update(costs)
        update, batch = costs["DEKF.update alone"], costs["DEKF.estimate, per sample"]
        observed, alone = rows["env + pilot + observer(DEKF)"], rows["env + pilot"]
        # what the observer adds beyond the filter's arithmetic (the "own cost")
        own = tuple(o - a - b for o, a, b in zip(observed, alone, batch, strict=True))
        rows["observer's own cost (DEKF, dicts)"] = own
        print(f"{task}:")
        print(f"  {'':40s} {'median':>8s} {'minimum':>8s}   (minimum: x real time)")
        for name, (median, best) in rows.items():
            print(f"  {name:40s} {median * 1e6:8.2f} {best * 1e6:8.2f}   {0.01 / best:8.0f}x")
        print(f"  DEKF.update / estimate per sample (minima) {update[1] / batch[1]:8.1f}x")
        print(f"  observer's own cost / estimate per sample (medians) {own[0] / batch[0]:8.1f}x")
        alone = rows["env + pilot"][0]
        for name in [n for n in rows if n.startswith("env + pilot + observer(")]:
            print(f"  env + pilot over {name} (medians) {alone / rows[name][0]:8.2f}x")


if __name__ == "__main__":
    main()
