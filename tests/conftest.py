"""What every test process shares."""

import os
import sys

if "PYTEST_XDIST_WORKER" in os.environ:
    # make test runs one pytest worker a core: a worker whose torch, OpenMP and BLAS
    # thread pools each took every core spun them against the other workers (measured:
    # the agents' tests took 92 s on 2 cores so, 56 s with one thread a worker). The
    # variables are read when those libraries load, which is after this file; a value
    # the user set is kept, and numpy loaded already (by a plugin) is limited here
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    if "numpy" in sys.modules and os.environ["OPENBLAS_NUM_THREADS"] == "1":
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
