"""Numerical toolkit for linear (parameter-varying) systems with delays.

Everything the other packages need to turn a block diagram into sampled signals:

* :func:`pade` -- Padé approximant of ``exp(-tau s)`` of any order (thesis eq. 4).
* :func:`tf_to_ccf` -- transfer function to controllable canonical form (thesis eqs.
  4.6-4.7), batched over leading axes so an LPV model builds all its samples at once.
* :func:`interconnect` -- block diagram (blocks, summing junctions, external inputs)
  to one state-space model, batched; exact delays are cut out as delay channels.
* :func:`discretize` -- exact zero-order-hold discretisation plus the first-order-hold
  (ramp) input matrix, batched, by one matrix exponential of an augmented matrix.
* :func:`simulate_lpv` -- compiled stepping of a discrete LPV system whose matrices may
  change every sample, with delay channels read from a fractional delay line.
* :func:`lpv_output_step`, :func:`lpv_state_step`, :func:`read_smooth`,
  :func:`read_held` -- the numba kernels of one sample, for kernels elsewhere that step
  the same way (they live in :mod:`~manualcontrol.envs._dynamics_kernels`).
* :class:`DelayLine` -- bounded-memory online delay line with bicubic interpolation
  of value and derivative (Boer & Kenyon 1998, Appendix).

Conventions: polynomial coefficients in descending powers of ``s`` (as scipy.signal);
state-space arrays may carry leading batch axes, ``A`` of shape ``(..., n, n)``.

The exponentials and the LPV loop run in C (``_dynamics_native.c``) wherever it builds
and as numba kernels elsewhere (``MANUALCONTROL_NATIVE=0``, no compiler), the same
numbers bit for bit; this module imports numba only when it needs those kernels, so a
process that discretises and simulates through the C port never pays for it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs import _dynamics_native
from manualcontrol.envs._expm import expm_batch
from manualcontrol.envs._validation import check_choice, check_int, check_positive

if TYPE_CHECKING:
    from manualcontrol.envs._dynamics_kernels import (
        lpv_output_step,
        lpv_state_step,
        read_held,
        read_smooth,
    )

__all__ = [
    "Block",
    "DelayChannel",
    "DelayLine",
    "Discretization",
    "Interconnection",
    "StateSpace",
    "discretize",
    "frequency_response",
    "interconnect",
    "lpv_output_step",
    "lpv_state_step",
    "pade",
    "pade_coefficients",
    "poly_multiply",
    "read_held",
    "read_smooth",
    "simulate_lpv",
    "tf_to_ccf",
]

FloatArray = NDArray[np.float64]

#: The numba kernels exported here, imported from their module on first use (PEP 562).
_KERNELS = ("lpv_output_step", "lpv_state_step", "read_held", "read_smooth")


def __getattr__(name: str) -> object:
    """One of :data:`_KERNELS`, from :mod:`~manualcontrol.envs._dynamics_kernels`."""
    if name in _KERNELS:
        from manualcontrol.envs import _dynamics_kernels

        value = getattr(_dynamics_kernels, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# --------------------------------------------------------------------------- Padé


def pade_coefficients(order: int) -> FloatArray:
    """Coefficients ``c_k`` of the order-``m`` Padé delay polynomial, ascending in k.

    Thesis eq. 4: ``exp(-tau s) ≈ Σ c_k (-tau s)^k / Σ c_k (tau s)^k`` with
    ``c_k = (2m - k)! / (k! (m - k)!)``, here divided by ``c_0 = (2m)!/m!`` so that
    the constant terms are 1. For m = 3 this is 120, 60, 12, 1 over 120 (Popovici
    eqs. 40-41).
    """
    m = check_int("order", order, minimum=0)
    raw = [
        math.factorial(2 * m - k) / (math.factorial(k) * math.factorial(m - k))
        for k in range(m + 1)
    ]
    return np.asarray(raw, dtype=np.float64) / raw[0]


def pade(tau: ArrayLike, order: int) -> tuple[FloatArray, FloatArray]:
    """Numerator and denominator of the Padé approximant of ``exp(-tau s)``.

    Parameters
    ----------
    tau
        Delay in seconds, ``>= 0``; a scalar or an array (batch of delays).
    order
        Approximation order ``m >= 0`` (numerator and denominator degree).

    Returns
    -------
    num, den
        Arrays of shape ``(*tau.shape, m + 1)``, descending powers of ``s``, both
        with constant term 1 (thesis eq. 4). ``den[..., k] = c_{m-k} tau^{m-k}`` and
        ``num`` is the same with ``-tau``.

    """
    m = check_int("order", order, minimum=0)
    tau_array = np.asarray(tau, dtype=np.float64)
    if not np.all(np.isfinite(tau_array)):
        raise ValueError(f"tau must be finite, got {tau!r}")
    if np.any(tau_array < 0.0):
        raise ValueError(f"tau must be >= 0 (a delay, not a preview), got {tau!r}")
    c = pade_coefficients(m)
    powers = np.arange(m, -1, -1)  # descending
    den = c[powers] * tau_array[..., None] ** powers
    num = c[powers] * (-tau_array[..., None]) ** powers
    return num, den


# ------------------------------------------------------------------- polynomials


def poly_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Product of polynomials in descending powers, batched over leading axes."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    batch = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    out = np.zeros((*batch, a.shape[-1] + b.shape[-1] - 1))
    for i in range(a.shape[-1]):
        out[..., i : i + b.shape[-1]] += a[..., i : i + 1] * b
    return out


# ------------------------------------------------------------------ state space


@dataclass(frozen=True)
class StateSpace:
    """Continuous or discrete linear model ``x' = A x + B u``, ``y = C x + D u``.

    Arrays may carry the same leading batch axes (one model per sample of an LPV
    trajectory). Shapes: ``A (..., n, n)``, ``B (..., n, m)``, ``C (..., p, n)``,
    ``D (..., p, m)``.
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray

    def __post_init__(self) -> None:
        arrays = {name: np.asarray(getattr(self, name), dtype=np.float64) for name in "ABCD"}
        for name, array in arrays.items():
            if array.ndim < 2:
                raise ValueError(f"{name} must have at least 2 dimensions, got shape {array.shape}")
            object.__setattr__(self, name, array)
        n = arrays["A"].shape[-1]
        m = arrays["B"].shape[-1]
        p = arrays["C"].shape[-2]
        expected = {"A": (n, n), "B": (n, m), "C": (p, n), "D": (p, m)}
        for name, shape in expected.items():
            if arrays[name].shape[-2:] != shape:
                raise ValueError(
                    f"{name} must end in shape {shape} for a model with {n} states, "
                    f"{m} inputs and {p} outputs, got {arrays[name].shape}"
                )

    @property
    def n_states(self) -> int:
        """Number of states ``n``."""
        return self.A.shape[-1]

    @property
    def n_inputs(self) -> int:
        """Number of inputs ``m``."""
        return self.B.shape[-1]

    @property
    def n_outputs(self) -> int:
        """Number of outputs ``p``."""
        return self.C.shape[-2]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading axes shared by the matrices (``()`` for one model)."""
        return np.broadcast_shapes(
            self.A.shape[:-2], self.B.shape[:-2], self.C.shape[:-2], self.D.shape[:-2]
        )


def tf_to_ccf(num: ArrayLike, den: ArrayLike) -> StateSpace:
    """Controllable canonical form of ``num(s)/den(s)`` (thesis eqs. 4.6-4.7).

    For ``(b_{n-1} s^{n-1} + ... + b_0)/(s^n + a_{n-1} s^{n-1} + ... + a_0)`` the
    realisation is the companion matrix with last row ``-a_0 ... -a_{n-1}``,
    ``B = [0 ... 0 1]^T`` and ``C = [b_0 ... b_{n-1}]``; a proper (biproper) transfer
    function first splits off its feedthrough ``D``. Coefficient arrays are in
    descending powers and may have leading batch axes (one transfer function per
    sample); the leading denominator coefficient must be non-zero everywhere.
    """
    num = np.atleast_1d(np.asarray(num, dtype=np.float64))
    den = np.atleast_1d(np.asarray(den, dtype=np.float64))
    if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
        raise ValueError("num and den must be finite")
    n = den.shape[-1] - 1
    if num.shape[-1] > den.shape[-1]:
        raise ValueError(
            f"transfer function must be proper: numerator degree {num.shape[-1] - 1} "
            f"exceeds denominator degree {n}"
        )
    lead = den[..., :1]
    if np.any(lead == 0.0):
        raise ValueError("den must have a non-zero leading coefficient (descending powers)")
    batch = np.broadcast_shapes(num.shape[:-1], den.shape[:-1])
    a = np.broadcast_to(den / lead, (*batch, n + 1))
    b = np.zeros((*batch, n + 1))
    b[..., n + 1 - num.shape[-1] :] = num / lead
    d = b[..., :1]
    remainder = b - d * a  # strictly proper part, remainder[..., 0] == 0
    A = np.zeros((*batch, n, n))
    if n > 0:
        A[..., np.arange(n - 1), np.arange(1, n)] = 1.0
        A[..., n - 1, :] = -a[..., :0:-1]
    B = np.zeros((*batch, n, 1))
    if n > 0:
        B[..., n - 1, 0] = 1.0
    C = remainder[..., :0:-1][..., None, :]
    D = d[..., None]
    return StateSpace(A, B, C, D)


def frequency_response(system: StateSpace, omega: ArrayLike) -> NDArray[np.complex128]:
    """Complex response ``C (jω I - A)^{-1} B + D`` of an unbatched model.

    Returns an array of shape ``(len(omega), p, m)``.
    """
    if system.batch_shape:
        raise ValueError(
            f"frequency_response needs one model, got batch shape {system.batch_shape}"
        )
    omega = np.atleast_1d(np.asarray(omega, dtype=np.float64))
    n = system.n_states
    eye = np.eye(n)
    out = np.empty((omega.shape[0], system.n_outputs, system.n_inputs), dtype=np.complex128)
    for i, w in enumerate(omega):
        out[i] = system.C @ np.linalg.solve(1j * w * eye - system.A, system.B) + system.D
    return out


# ---------------------------------------------------------------- interconnection


def _product(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` where one factor is a single matrix and the other a (long) stack.

    numpy multiplies a stack matrix by matrix (about 0.2 us each for these sizes);
    folding the stack into one tall matrix makes it a single BLAS product.
    """
    if b.ndim == 2 and a.ndim > 2:
        return (a.reshape(-1, a.shape[-1]) @ b).reshape(*a.shape[:-1], b.shape[-1])
    if a.ndim == 2 and b.ndim > 2:
        flipped = np.swapaxes(b, -1, -2)
        product = flipped.reshape(-1, flipped.shape[-1]) @ a.T
        return np.swapaxes(product.reshape(*flipped.shape[:-1], a.shape[0]), -1, -2)
    return a @ b


@dataclass(frozen=True)
class Block:
    """A state-space block with named input and output signals."""

    system: StateSpace
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "outputs", tuple(self.outputs))
        if len(self.inputs) != self.system.n_inputs:
            raise ValueError(
                f"block has {self.system.n_inputs} inputs but {len(self.inputs)} "
                f"input names {self.inputs}"
            )
        if len(self.outputs) != self.system.n_outputs:
            raise ValueError(
                f"block has {self.system.n_outputs} outputs but {len(self.outputs)} "
                f"output names {self.outputs}"
            )


@dataclass(frozen=True)
class DelayChannel:
    """An exact delay ``target(t) = source(t - delay)`` cut out of a block diagram.

    :func:`interconnect` treats ``target`` as an extra external input and ``source``
    as an extra output; :func:`simulate_lpv` closes the channel through a delay line.
    """

    source: str
    target: str


class Interconnection(NamedTuple):
    """Result of :func:`interconnect`: one model plus the names of its signals."""

    system: StateSpace
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    delay_inputs: tuple[int, ...]
    delay_outputs: tuple[int, ...]


def interconnect(
    blocks: Sequence[Block],
    inputs: Sequence[str],
    outputs: Sequence[str],
    sums: Mapping[str, Mapping[str, float]] | None = None,
    delays: Sequence[DelayChannel] = (),
) -> Interconnection:
    """Connect named blocks into one (possibly batched) state-space model.

    Every block input and requested output is a *signal*: an external input, a
    block output, or a summing junction ``sums[name] = {signal: gain, ...}``.
    Writing the block outputs as ``Y = C x + D U`` and the block inputs as
    ``U = M Y + N W`` (``W`` the external inputs), the connected model is

        Y = L (C x + D N W),  L = (I - D M)^{-1}
        x' = (A + B M L C) x + B (M L D N + N) W
        z  = P L C x + (P L D N + Q) W

    for requested outputs ``z = P Y + Q W``. A singular ``I - D M`` is an algebraic
    loop and raises. Delay channels append their targets to the external inputs and
    their sources to the outputs (indices returned in the result).
    """
    sums = dict(sums or {})
    delays = tuple(delays)
    external = tuple(inputs) + tuple(channel.target for channel in delays)
    requested = tuple(outputs) + tuple(channel.source for channel in delays)
    block_outputs: list[str] = []
    for block in blocks:
        block_outputs.extend(block.outputs)
    names = block_outputs + list(external) + list(sums)
    if len(set(names)) != len(names):
        duplicated = sorted({name for name in names if names.count(name) > 1})
        raise ValueError(
            f"signal names must be unique across blocks, inputs and sums: {duplicated}"
        )
    n_y, n_w = len(block_outputs), len(external)
    resolved: dict[str, FloatArray] = {}
    for i, name in enumerate(block_outputs):
        resolved[name] = np.eye(n_y + n_w)[i]
    for j, name in enumerate(external):
        resolved[name] = np.eye(n_y + n_w)[n_y + j]

    def resolve(name: str, trail: tuple[str, ...] = ()) -> FloatArray:
        if name in resolved:
            return resolved[name]
        if name not in sums:
            raise ValueError(f"signal {name!r} is not a block output, an input or a sum")
        if name in trail:
            raise ValueError(f"summing junctions form a cycle: {' -> '.join((*trail, name))}")
        row = np.zeros(n_y + n_w)
        for term, gain in sums[name].items():
            row = row + float(gain) * resolve(term, (*trail, name))
        resolved[name] = row
        return row

    block_inputs = [name for block in blocks for name in block.inputs]
    MN = np.array([resolve(name) for name in block_inputs]).reshape(len(block_inputs), n_y + n_w)
    PQ = np.array([resolve(name) for name in requested]).reshape(len(requested), n_y + n_w)
    M, N = MN[:, :n_y], MN[:, n_y:]
    P, Q = PQ[:, :n_y], PQ[:, n_y:]

    batch = np.broadcast_shapes(*(block.system.batch_shape for block in blocks))
    n_x = sum(block.system.n_states for block in blocks)
    n_u = len(block_inputs)
    A = np.zeros((*batch, n_x, n_x))
    B = np.zeros((*batch, n_x, n_u))
    C = np.zeros((*batch, n_y, n_x))
    D = np.zeros((*batch, n_y, n_u))
    ix = iu = iy = 0
    for block in blocks:
        s = block.system
        nx, nu, ny = s.n_states, s.n_inputs, s.n_outputs
        A[..., ix : ix + nx, ix : ix + nx] = s.A
        B[..., ix : ix + nx, iu : iu + nu] = s.B
        C[..., iy : iy + ny, ix : ix + nx] = s.C
        D[..., iy : iy + ny, iu : iu + nu] = s.D
        ix, iu, iy = ix + nx, iu + nu, iy + ny
    DM = _product(D, M)
    if not DM.any():
        # no feedthrough closes a loop (the usual case): L = I, and solving with the
        # identity would return C and D N unchanged at the cost of one LU per sample
        LC, LDN = C, _product(D, N)
    else:
        loop = np.eye(n_y) - DM
        try:
            LC = np.linalg.solve(loop, C)
            LDN = np.linalg.solve(loop, _product(D, N))
        except np.linalg.LinAlgError as error:
            raise ValueError(
                "the block diagram has an algebraic loop (I - D M is singular)"
            ) from error
    system = StateSpace(
        A + _product(B, M) @ LC,
        B @ (_product(M, LDN) + N),
        _product(P, LC),
        _product(P, LDN) + Q,
    )
    return Interconnection(
        system,
        external,
        requested,
        tuple(range(len(inputs), n_w)),
        tuple(range(len(outputs), len(requested))),
    )


# ---------------------------------------------------------------- discretisation


class Discretization(NamedTuple):
    """Exact discretisation of ``x' = A x + B u`` over one sample ``dt``.

    ``x[k+1] = phi x[k] + gamma u[k] + gamma_ramp (u[k+1] - u[k])``: with
    ``gamma_ramp`` omitted (zero-order hold, inputs constant over the sample) this is
    exact for piecewise-constant inputs; with it (first-order hold) it is exact for
    inputs that are linear between samples.
    """

    phi: FloatArray
    gamma: FloatArray
    gamma_ramp: FloatArray


def discretize(
    A: ArrayLike, B: ArrayLike, dt: float, ramp_inputs: Sequence[int] | None = None
) -> Discretization:
    """Zero- and first-order-hold discretisation by one augmented matrix exponential.

    ``expm([[A, B, 0], [0, 0, S/dt], [0, 0, 0]] dt)`` holds ``phi = e^{A dt}``,
    ``gamma = ∫_0^dt e^{A s} ds B`` and the ramp matrix ``gamma_ramp = (1/dt) ∫_0^dt
    e^{A (dt - s)} s ds B S`` in its first block row. ``S`` selects the inputs whose
    ramp term is wanted, ``ramp_inputs`` (default all); the other columns of
    ``gamma_ramp`` are zero. ``A`` and ``B`` may have leading batch axes; each matrix
    is exponentiated by a compiled Al-Mohy & Higham (2009) scaling and squaring (the
    algorithm of :func:`scipy.linalg.expm`, without its per-call overhead), a run of
    equal consecutive matrices once.

    The cost is that of the exponentials, cubic in their size, so they are kept
    small: only the ramped inputs get a ramp column, and when the states fall into
    groups that ``A`` never couples (anywhere along the batch; e.g. a pilot's pre- and
    post-delay dynamics, joined only through a delay channel) each group is
    exponentiated with just its own states and the inputs that reach it. The
    exponential of a block-diagonal matrix is block diagonal, so this changes only
    rounding.
    """
    dt = check_positive("dt", dt)
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise ValueError("A and B must be finite")
    n, m = A.shape[-1], B.shape[-1]
    if ramp_inputs is None:
        ramped = np.arange(m)
    else:
        ramped = np.unique(np.asarray(ramp_inputs, dtype=np.int64).reshape(-1))
        if ramped.size and (ramped[0] < 0 or ramped[-1] >= m):
            raise ValueError(
                f"ramp_inputs must be input indices in [0, {m - 1}], got {list(ramp_inputs)}"
            )
    batch = np.broadcast_shapes(A.shape[:-2], B.shape[:-2])
    A = np.broadcast_to(A, (*batch, n, n))
    B = np.broadcast_to(B, (*batch, n, m))
    groups = _uncoupled_states(A)
    if len(groups) <= 1:
        return _discretize_block(A, B, dt, ramped)
    phi = np.zeros((*batch, n, n))
    gamma = np.zeros((*batch, n, m))
    gamma_ramp = np.zeros((*batch, n, m))
    reached = np.any(B != 0.0, axis=tuple(range(len(batch))))  # (n, m)
    for states in groups:
        inputs = np.flatnonzero(reached[states].any(axis=0))
        local_ramped = np.flatnonzero(np.isin(inputs, ramped))
        part = _discretize_block(
            A[..., states[:, None], states], B[..., states[:, None], inputs], dt, local_ramped
        )
        phi[..., states[:, None], states] = part.phi
        gamma[..., states[:, None], inputs] = part.gamma
        gamma_ramp[..., states[:, None], inputs] = part.gamma_ramp
    return Discretization(phi, gamma, gamma_ramp)


def _uncoupled_states(A: FloatArray) -> list[NDArray[np.int64]]:
    """Groups of states that ``A`` (over its whole batch) never couples, in order."""
    n = A.shape[-1]
    coupled = np.any(A != 0.0, axis=tuple(range(A.ndim - 2))) if A.ndim > 2 else A != 0.0
    coupled = coupled | coupled.T
    group = np.full(n, -1)
    count = 0
    for start in range(n):
        if group[start] >= 0:
            continue
        group[start] = count
        frontier = [start]
        while frontier:
            state = frontier.pop()
            for neighbour in np.flatnonzero(coupled[state]):
                if group[neighbour] < 0:
                    group[neighbour] = count
                    frontier.append(int(neighbour))
        count += 1
    return [np.flatnonzero(group == g) for g in range(count)]


def _discretize_block(
    A: FloatArray, B: FloatArray, dt: float, ramped: NDArray[np.int64]
) -> Discretization:
    """:func:`discretize` by one augmented exponential per matrix of the batch."""
    n, m = A.shape[-1], B.shape[-1]
    r = ramped.shape[0]
    batch = A.shape[:-2]
    size = n + m + r
    augmented = np.zeros((*batch, size, size))
    augmented[..., :n, :n] = A * dt
    augmented[..., :n, n : n + m] = B * dt
    augmented[..., n + ramped, n + m + np.arange(r)] = 1.0
    exponentials = expm_batch(augmented.reshape(-1, size, size)).reshape(augmented.shape)
    gamma_ramp = np.zeros((*batch, n, m))
    gamma_ramp[..., ramped] = exponentials[..., :n, n + m :]
    return Discretization(
        np.ascontiguousarray(exponentials[..., :n, :n]),
        np.ascontiguousarray(exponentials[..., :n, n : n + m]),
        gamma_ramp,
    )


# ------------------------------------------------------------------ LPV stepping


def _per_sample(name: str, array: ArrayLike, n_samples: int, trailing: int) -> FloatArray:
    """Give ``array`` a leading time axis of length 1 (shared) or ``n_samples``."""
    array = np.asarray(array, dtype=np.float64)
    if array.ndim == trailing:
        array = array[None]
    if array.ndim != trailing + 1 or array.shape[0] not in (1, n_samples):
        raise ValueError(
            f"{name} must have shape {('n_samples',) + ('.',) * trailing} with n_samples "
            f"{n_samples} or 1, or drop the time axis; got {array.shape}"
        )
    return np.ascontiguousarray(array)


def simulate_lpv(
    discretization: Discretization,
    C: ArrayLike,
    D: ArrayLike,
    inputs: ArrayLike,
    dt: float,
    x0: ArrayLike | None = None,
    delay_inputs: Sequence[int] = (),
    delay_outputs: Sequence[int] = (),
    delays: ArrayLike | None = None,
    held_states: Sequence[int] = (),
    history: str = "rest",
) -> tuple[FloatArray, FloatArray]:
    """Step a discrete linear parameter-varying system, with exact delay channels.

    Each sample ``k`` uses its own ``phi[k], gamma[k], C[k], D[k]`` when the arrays
    carry a leading time axis of length ``n_samples`` (shared when it is absent or 1):

        y[k]   = C[k] x[k] + D[k] u[k]
        x[k+1] = phi[k] x[k] + gamma[k] u[k] + gamma_ramp[k] (s[k+1] - s[k])

    External inputs are held over each sample (zero-order hold). Delay channel ``i``
    feeds input ``delay_inputs[i]`` with output ``delay_outputs[i]`` delayed by
    ``delays[k, i]`` seconds. The delayed output has two parts, delayed each in the
    way that is exact for it:

    * its smooth part ``C x`` is read from the past by bicubic interpolation (Boer &
      Kenyon 1998, Appendix) and taken linear between samples (``s`` above, the
      first-order-hold ramp term): error second order in ``dt``;
    * its held part ``D u`` (held inputs passed straight through, such as a displayed
      error) is a staircase; the delayed staircase is replaced by its mean over the
      sample, exact when the delay is a whole number of samples and second order in
      ``dt`` otherwise.

    ``held_states`` lists states whose contribution to a delayed output counts as
    held (sampled-data loops, where a discretised element feeds a sampled display).
    The delay line starts at rest (zero before ``t = 0``, ``history="rest"``) or holds
    each delayed signal's first value before it (``history="initial"``: a run started
    from a state that had a past). Delays must be at least
    ``3 dt`` for the four interpolation samples to be in the past (shorter delays lose
    interpolation order, see :func:`read_smooth`).

    Returns
    -------
    states, outputs
        Arrays of shape ``(n_samples, n)`` and ``(n_samples, p)``.

    """
    dt = check_positive("dt", dt)
    inputs = np.asarray(inputs, dtype=np.float64)
    if inputs.ndim != 2:
        raise ValueError(f"inputs must have shape (n_samples, n_inputs), got {inputs.shape}")
    n_samples = inputs.shape[0]
    phi = _per_sample("phi", discretization.phi, n_samples, 2)
    gamma = _per_sample("gamma", discretization.gamma, n_samples, 2)
    gamma_ramp = _per_sample("gamma_ramp", discretization.gamma_ramp, n_samples, 2)
    C = _per_sample("C", C, n_samples, 2)
    D = _per_sample("D", D, n_samples, 2)
    n_x, n_u = phi.shape[-1], gamma.shape[-1]
    if inputs.shape[1] != n_u:
        raise ValueError(f"inputs must have {n_u} columns, got {inputs.shape[1]}")
    x0 = np.zeros(n_x) if x0 is None else np.asarray(x0, dtype=np.float64).reshape(n_x)
    delay_inputs_array = np.asarray(delay_inputs, dtype=np.int64).reshape(-1)
    delay_outputs_array = np.asarray(delay_outputs, dtype=np.int64).reshape(-1)
    n_delay = delay_inputs_array.shape[0]
    if delay_outputs_array.shape[0] != n_delay:
        raise ValueError("delay_inputs and delay_outputs must have the same length")
    if n_delay:
        if delays is None:
            raise ValueError("delays must be given for delay channels")
        delay_array = np.asarray(delays, dtype=np.float64)
        delay_array = np.broadcast_to(
            delay_array.reshape(delay_array.shape[0] if delay_array.ndim else 1, -1),
            (n_samples, n_delay),
        )
        if not np.all(np.isfinite(delay_array)) or np.any(delay_array < 0.0):
            raise ValueError("delays must be finite and >= 0 seconds")
        delay_samples = np.ascontiguousarray(delay_array / dt)
        history_pad = int(np.ceil(delay_samples.max())) + 4
    else:
        delay_samples = np.zeros((n_samples, 0))
        history_pad = 0
    held_mask = np.zeros(n_x, dtype=np.bool_)
    held_mask[np.asarray(held_states, dtype=np.int64)] = True
    check_choice("history", history, ("rest", "initial"))
    if gamma_ramp.shape[0] != gamma.shape[0]:
        # the kernels index both with gamma's sample: one shared, the other per sample
        count = max(gamma.shape[0], gamma_ramp.shape[0])
        gamma = np.ascontiguousarray(np.broadcast_to(gamma, (count, *gamma.shape[1:])))
        gamma_ramp = np.ascontiguousarray(
            np.broadcast_to(gamma_ramp, (count, *gamma_ramp.shape[1:]))
        )
    arguments = (
        phi,
        gamma,
        gamma_ramp,
        C,
        D,
        np.ascontiguousarray(inputs),
        np.ascontiguousarray(x0),
        _channel_indices("delay_inputs", delay_inputs_array, n_u),
        _channel_indices("delay_outputs", delay_outputs_array, C.shape[1]),
        delay_samples,
        history_pad,
        held_mask,
        history == "initial",
    )
    lib = _dynamics_native.library()
    if lib is not None:
        return _dynamics_native.simulate_lpv(lib, *arguments)
    from manualcontrol.envs._dynamics_kernels import simulate_lpv_kernel

    return simulate_lpv_kernel(*arguments)


def _channel_indices(name: str, indices: NDArray[np.int64], size: int) -> NDArray[np.int64]:
    """Delay-channel indices into ``size`` signals, negative ones counted from the end.

    The kernels index with them unchecked; one outside the signals raises here.
    """
    if np.any((indices < -size) | (indices >= size)):
        raise ValueError(f"{name} must be indices into {size} signals, got {indices.tolist()}")
    return np.ascontiguousarray(np.where(indices < 0, indices + size, indices))


# ------------------------------------------------------------------- delay line


@dataclass
class DelayLine:
    """Online fractional delay line with bounded memory.

    Push one sample per ``dt``; read the signal ``delay`` seconds before the newest
    sample, with bicubic interpolation (Boer & Kenyon 1998, Appendix) of the value
    and its time derivative. The delay may change on every read. Memory is
    ``ceil(max_delay/dt) + 4`` samples. Before the first push the line holds
    ``initial``.
    """

    max_delay: float
    dt: float
    initial: float = 0.0
    _buffer: FloatArray = field(init=False, repr=False)
    _count: int = field(init=False, repr=False, default=0)

    def __post_init__(self) -> None:
        self.max_delay = check_positive("max_delay", self.max_delay, allow_zero=True)
        self.dt = check_positive("dt", self.dt)
        size = math.ceil(self.max_delay / self.dt - 1e-9) + 4
        self._buffer = np.full(size, float(self.initial))
        self._count = 0

    def reset(self, initial: float | None = None) -> None:
        """Forget all samples; fill with ``initial`` (default: the constructor's)."""
        self._buffer.fill(self.initial if initial is None else float(initial))
        self._count = 0

    def push(self, value: float) -> None:
        """Append the newest sample."""
        self._buffer[self._count % self._buffer.shape[0]] = value
        self._count += 1

    def _window(self, delay: float) -> tuple[FloatArray, float]:
        if not (0.0 <= delay <= self.max_delay + 1e-12):
            raise ValueError(f"delay must lie in [0, {self.max_delay:g}] s, got {delay!r}")
        size = self._buffer.shape[0]
        # oldest-first copy of the ring; position of the read point within it
        start = self._count % size
        ordered = np.concatenate((self._buffer[start:], self._buffer[:start]))
        return ordered, (size - 1) - delay / self.dt

    def read(self, delay: float) -> float:
        """Signal value ``delay`` seconds before the newest sample."""
        from manualcontrol.envs._interpolation import interpolate_at

        ordered, position = self._window(delay)
        return float(interpolate_at(ordered, position)[0])

    def read_with_derivative(self, delay: float) -> tuple[float, float]:
        """Value and time derivative ``delay`` seconds before the newest sample."""
        from manualcontrol.envs._interpolation import interpolate_at

        ordered, position = self._window(delay)
        value, slope = interpolate_at(ordered, position)
        return float(value), float(slope) / self.dt
