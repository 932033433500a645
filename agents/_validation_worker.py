"""A second process that flies a training's validations while the training goes on.

With ``select_every`` (:class:`~manualcontrol.agents.training.TrainingConfig`) a
training stops every so many steps to fly its policy on the validation episodes: on
the tracking recipes about a seventh of the training's time, on one core, while the
training itself (one torch thread, its environments stepped one after another) leaves
a second core idle. :func:`~manualcontrol.agents.training.train` therefore hands each
validation's weights to this worker and reads the scores when training ends. The
worker rebuilds the same policy from the configuration, loads the weights and calls
the same :func:`~manualcontrol.agents.training.validation_score` on one torch thread,
so each score is the one the training process would have computed, bit for bit, and
the kept weights are the same.

Protocol, over the worker's standard input and output: the parent writes pickled jobs
``(config_dict, weights, episodes)`` (``weights``: the policy's state as numpy arrays)
and ``None`` when there are no more; the worker answers each job in order with a
pickled ``("score", value)`` or ``("error", message)``. A thread reads the jobs as
they come, so the parent never waits on a full pipe while a validation runs.

Run as ``python -m manualcontrol.agents._validation_worker`` (by the parent only).
"""

from __future__ import annotations

import os
import pickle
import queue
import signal
import sys
import threading
from typing import Any


def _read_jobs(source: Any, jobs: queue.Queue[Any]) -> None:
    while True:
        try:
            job = pickle.load(source)
        except Exception:  # the end of input, or a job cut short: the parent is gone
            job = None  # stop after the jobs already read
        jobs.put(job)
        if job is None:
            return


def main() -> None:
    """Answer validation jobs from standard input until ``None`` or the end of input."""
    # the parent's Ctrl-C reaches this process too: the parent ends it, so no second
    # traceback on the terminal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # the replies own standard output: anything written there, by Python or by a
    # compiled library, goes to standard error instead
    output = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import torch

    from manualcontrol.agents.training import (
        TrainingConfig,
        _rebuilt_policy,
        validation_score,
    )

    torch.set_num_threads(1)  # as train() does: the same sums in the same order
    jobs: queue.Queue[Any] = queue.Queue()
    reader = threading.Thread(target=_read_jobs, args=(sys.stdin.buffer, jobs), daemon=True)
    reader.start()
    config = policy = None  # one training's: built at its first job
    while (job := jobs.get()) is not None:
        config_data, weights, episodes = job
        try:
            if policy is None:
                config = TrainingConfig.from_dict(config_data)
                policy = _rebuilt_policy(config)
            policy.load_state_dict({name: torch.from_numpy(w) for name, w in weights.items()})
            reply: tuple[str, Any] = ("score", validation_score(policy, config, episodes))
        except Exception as error:  # the parent raises it, named, where it reads the score
            reply = ("error", f"{type(error).__name__}: {error}")
        try:
            pickle.dump(reply, output, protocol=pickle.HIGHEST_PROTOCOL)
            output.flush()
        except BrokenPipeError:
            return  # the training ended without reading: nobody is left to answer


if __name__ == "__main__":
    main()
