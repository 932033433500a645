"""The install step's compilation jobs run: each one compiles (or loads) its kernels.

``make`` compiles the kernels into numba's cache at install so that first use loads
them; a job that broke would leave its kernels to compile at first use without a
word, so each job is run here as the install runs it.
"""

import pytest

from manualcontrol.bench.compile_kernels import JOBS, _run_job, main
from manualcontrol.envs import _native


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
