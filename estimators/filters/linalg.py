"""Small dense linear algebra for the filters, compiled, allocation-free.

Everything works in place on caller-owned arrays (numba with ``_nrt=False``: no array
is allocated or reference counted inside a step). Covariances are kept symmetric by
:func:`symmetrise` after every update; systems are solved through a Cholesky factor,
never by forming an inverse (as dynamax's ``psd_solve``).

The kernels live in :mod:`~manualcontrol.estimators.filters._linalg_kernels`, imported
on first use (a process whose filters run in C never imports numba); the constants they
read stay here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from manualcontrol.envs._lazy import kernels_on_first_use

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.filters._linalg_kernels import (
        add_product,
        cholesky,
        cholesky_semidefinite,
        cholesky_semidefinite_pivoted,
        cholesky_solve_rows,
        log_determinant,
        matmul,
        matmul_transposed,
        symmetrise,
    )

__all__ = [
    "TINY",
    "add_product",
    "cholesky",
    "cholesky_semidefinite",
    "cholesky_semidefinite_pivoted",
    "cholesky_solve_rows",
    "log_determinant",
    "matmul",
    "matmul_transposed",
    "symmetrise",
]

# numba kernels read this module's constants
#: Magnitude below which covariance entries are flushed to zero (subnormal range).
#: A state without process noise that the measurements pin down has a variance that
#: decays towards zero; left alone it reaches subnormal numbers, whose arithmetic is a
#: hundred times slower, and flickers around zero by rounding.
TINY = 1e-290


#: Pivots below this fraction of the largest diagonal entry count as zero in
#: :func:`cholesky_semidefinite` (a few hundred times the double precision epsilon).
SEMIDEFINITE_TOLERANCE = 1e-13


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "symmetrise",
    "cholesky",
    "cholesky_semidefinite",
    "cholesky_semidefinite_pivoted",
    "cholesky_solve_rows",
    "log_determinant",
    "matmul",
    "matmul_transposed",
    "add_product",
    "semidefinite_floor",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._linalg_kernels", _KERNELS
)
