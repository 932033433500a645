"""The install step's compilation jobs run: each one compiles (or loads) its kernels.

``make`` compiles the kernels into numba's cache at install so that first use loads
them; a job that broke would leave its kernels to compile at first use without a
word, so each job is run here as the install runs it.
"""

import os
import subprocess
import sys

import pytest

from manualcontrol.bench.compile_kernels import (
    JOBS,
    NUMBA_REFERENCE,
    REFERENCE_OPT_LEVEL,
    _run_job,
    main,
    selected_jobs,
)
from manualcontrol.envs import _native
from manualcontrol.estimators.registry import ESTIMATORS


@pytest.mark.parametrize("name", list(JOBS))
def test_each_compilation_job_runs(name):
    if name.startswith("C ports") and _native._compiler() is None:
        pytest.skip("no C compiler here: the C ports cannot be built (numba runs instead)")
    ran, seconds, failure = _run_job(name)
    assert ran == name and seconds >= 0.0
    assert failure is None, failure


def test_a_bad_worker_count_is_refused_naming_the_flag(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--workers", "0"])
    assert exit_.value.code == 2
    assert "--workers must be a whole number >= 1, got 0" in capsys.readouterr().err


def test_every_c_ported_estimators_numba_job_is_a_reference_job():
    ported = [
        name
        for name, entry in ESTIMATORS.items()
        if getattr(type(entry.build({})), "_native_binding", None) is not None
    ]
    assert ported and set(ported) <= set(NUMBA_REFERENCE)
    assert "LPV toolkit" in NUMBA_REFERENCE
    assert not {"C ports", "tracking simulations", "environments"} & set(NUMBA_REFERENCE)


def test_the_install_step_compiles_the_replaced_numba_kernels_only_where_no_port_runs(
    monkeypatch,
):
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    monkeypatch.setattr(_native, "_compiler", lambda: ["cc"])
    assert selected_jobs() == [name for name in JOBS if name not in NUMBA_REFERENCE]
    assert selected_jobs(numba_reference=True) == list(NUMBA_REFERENCE)
    monkeypatch.setattr(_native, "_compiler", lambda: None)  # no compiler: numba runs
    assert selected_jobs() == list(JOBS)
    monkeypatch.setattr(_native, "_compiler", lambda: ["cc"])
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert selected_jobs() == list(JOBS)


def test_the_install_step_says_what_it_left_to_the_tests(monkeypatch, capsys):
    import manualcontrol.bench.compile_kernels as compiling

    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    monkeypatch.setattr(_native, "_compiler", lambda: ["cc"])
    monkeypatch.setattr(
        compiling, "JOBS", {"C ports": lambda: None, **dict.fromkeys(NUMBA_REFERENCE)}
    )
    assert compiling.compile_kernels(1, print)
    out = capsys.readouterr().out
    assert "compiled: C ports" in out and "--numba-reference compiles them now" in out


#: Compiles one kernel through compile_kernels as the only job (a reference job, or an
#: install job) and prints the level numba compiled it at, from the worker.
LEVEL_PROBE = """
import sys
import numba
import manualcontrol.bench.compile_kernels as compile_kernels

def probe():
    numba.njit(lambda x: x + 1)(1)  # numba reads its environment again at a compile
    print("level", int(numba.core.config.OPT), flush=True)

reference = sys.argv[1] == "reference"
compile_kernels.JOBS = {"probe": probe}
compile_kernels.NUMBA_REFERENCE = ("probe",) if reference else ()
compile_kernels.compile_kernels(1, lambda line: None, numba_reference=reference)
print("after", compile_kernels.os.environ.get("NUMBA_OPT"))
"""


@pytest.mark.parametrize(
    ("mode", "user_level", "compiled_at"),
    [("reference", None, REFERENCE_OPT_LEVEL), ("reference", "2", "2"), ("install", None, "3")],
)
def test_the_reference_compiles_at_its_own_level_unless_numba_opt_names_one(
    mode, user_level, compiled_at
):
    environment = {key: value for key, value in os.environ.items() if key != "NUMBA_OPT"}
    if user_level is not None:
        environment["NUMBA_OPT"] = user_level
    printed = subprocess.run(
        [sys.executable, "-c", LEVEL_PROBE, mode],
        env=environment,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    # compiled at that level, and the environment left as it was found
    assert printed == ["level", compiled_at, "after", str(user_level)]
