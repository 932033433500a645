"""The estimators' internal model: the isolated pilot as a nonlinear state-space system.

A Kalman-filter estimator needs the pilot model of :mod:`manualcontrol.pilots.models`
as ``x' = f(x, inputs, p)``, ``u = g(x, inputs, p)`` with Jacobians in ``x`` and in the
parameters ``p``. :class:`InternalModel` derives these from the structure's one
definition, :meth:`~manualcontrol.pilots.models.PilotModel.channels`, with the model
delay as a Padé approximant (thesis Part I eq. 4) of a chosen order:

* the *main chain* is the post-delay transfer function times the delay approximant,
  ``post(s) Pade_tau(s)``, in controllable canonical form (thesis Part II eq. 4.7);
* every pre-delay *branch* ``pre_b(s)`` with dynamics gets its own canonical chain
  whose output, with the static branches, forms the main chain's input
  ``v = sum_b pre_b x_b`` (the split at the summing point, thesis Part II Sec. 5.2.1,
  eqs. 5.2-5.3). A branch fed by the previewed target ``ft_far`` is fed the
  *anticipated* target ``ft_ahead(t) = ft(t + tau_a)`` instead, through the extra
  delay ``exp(-tau_f* s)``, ``tau_f* = tau_a - tau_f`` (thesis eq. 26), also as a Padé
  approximant; the parameter slot of ``tau_f`` then holds ``tau_f*``.

The states are ordered as in the papers: main chain first (``x_1 .. x_5``), then the
branch chains (``x_6 .. x_9`` for the far view). For the precision model this
reproduces Popovici et al. (2017) eqs. 40-41 exactly, for the preview model thesis
Part I eqs. 45-46 (tests check both against the printed equations).

How the parameters enter
------------------------
The coefficients that :meth:`channels` returns are polynomials in the parameters
(``K_p omega^2``, ``2 zeta omega``, ``K_f omega_f`` ...). :func:`build_internal_model`
recovers each polynomial exactly by evaluating ``channels`` on a tensor grid of
parameter values (nodes ``0 .. d`` per parameter) and inverting the Vandermonde
matrices; the result is verified at random parameter values. The compiled kernels
evaluate these monomials and their analytic derivatives, multiply by the Padé
polynomials with forward-mode derivatives (value and gradient carried together) and
normalise to a monic denominator by the quotient rule. No derivative is approximated.

Parameters that enter the main chain's numerator only (``K_p``, ``K_v``) appear in
``g`` alone; the DEKF places them in its state filter (Popovici Sec. III-A, thesis
Sec. III-A), all others in the parameter filter.

The kernels live in :mod:`~manualcontrol.estimators.members._internal_model_kernels`,
imported on first use (a process whose filters run in C never imports numba).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import kernels_on_first_use
from manualcontrol.envs._validation import check_choice, check_int
from manualcontrol.pilots.models import PilotModel, make_model

__all__ = [
    "INPUT_SIGNALS",
    "InternalModel",
    "ModelEvaluation",
    "ModelKernel",
    "build_internal_model",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Filter input that replaces each perception of a pilot model.
INPUT_SIGNALS: dict[str, str] = {"e": "e", "y": "y", "ft_far": "ft_ahead"}
#: Preview-time parameter whose slot holds the apparent delay ``tau_f*`` (thesis eq. 26).
ANTICIPATED_PARAMETER = "tau_f"
_MAX_DEGREE = 3
_CHECK_POINTS = 7

#: What the compiled kernels read and write, one record per filter (each filter owns its
#: scratch): the model's tables (monomials, chains, branches), ``active`` (which
#: gradients to compute, see :meth:`InternalModel.active_table`), ``gradients`` (False:
#: values only, the unscented filters' case, which skips every derivative), the scratch of the
#: coefficient evaluation and its outputs ``negA, C, d`` with their gradients.
ModelKernel = namedtuple(
    "ModelKernel",
    [
        # tables
        "term_coef",
        "term_var",
        "term_exp",
        "term_slot",
        "chain_num",
        "chain_den",
        "chain_pade",
        "chain_offset",
        "chain_size",
        "chain_num_length",
        "chain_den_length",
        "branch_chain",
        "branch_input",
        "active",
        "gradients",
        # scratch
        "raw",
        "raw_grad",
        "num",
        "num_grad",
        "den",
        "den_grad",
        "pade_value",
        "pade_slope",
        # canonical-form coefficients and their gradients
        "negA",
        "negA_grad",
        "C",
        "C_grad",
        "d",
        "d_grad",
    ],
)


@dataclass(frozen=True)
class ModelEvaluation:
    """``f``, ``g`` and their Jacobians at one point (see :meth:`InternalModel.evaluate`).

    Attributes
    ----------
    f : ndarray, shape (n,)
        State derivative of the canonical states.
    F : ndarray, shape (n, n)
        ``df/dx``.
    dfdp : ndarray, shape (n, n_p)
        ``df/dp`` in :attr:`InternalModel.parameter_names` order.
    g : float
        Model output ``u``.
    dgdx : ndarray, shape (n,)
        ``dg/dx``.
    dgdp : ndarray, shape (n_p,)
        ``dg/dp``.

    """

    f: FloatArray
    F: FloatArray
    dfdp: FloatArray
    g: float
    dgdx: FloatArray
    dgdp: FloatArray


@dataclass(frozen=True, eq=False)
class InternalModel:
    """A pilot structure as compiled-kernel tables (build with :func:`build_internal_model`).

    Attributes
    ----------
    model : PilotModel
        The structure it was built from.
    delay_order : int
        Padé order of the model delay (and of the anticipation delay ``tau_f*``).
    parameter_names : tuple of str
        The model's parameters in model order; the slot of ``tau_f`` holds ``tau_f*``.
    input_names : tuple of str
        Filter inputs in order: ``("e",)`` for compensatory models, ``("ft_ahead",
        "y")`` for the preview model.
    gain_parameters : tuple of str
        Parameters that appear in the main chain's numerator only, hence only in ``g``.
    branch_parameters : tuple of str
        Parameters of the branches alone (the preview model's far-view ``K_f``,
        ``omega_f`` and the anticipation delay ``tau_f*``): what reaches the main chain
        through them, and nothing the main chain's input receives directly, depends on
        them.
    n_states : int
        Number of canonical states.
    input_states : tuple of int
        Per chain with states, the index of its input state (the last state of the
        chain, whose derivative the chain input drives); the first is the main chain's,
        Popovici eq. 25's ``x_5`` and thesis eq. 29's ``x_{s,e}``.

    The remaining attributes are the integer and float tables the kernels read.
    """

    model: PilotModel
    delay_order: int
    parameter_names: tuple[str, ...]
    input_names: tuple[str, ...]
    gain_parameters: tuple[str, ...]
    branch_parameters: tuple[str, ...]
    n_states: int
    input_states: tuple[int, ...]
    # monomials: coefficient, then (variable, exponent) pairs
    term_coef: FloatArray
    term_var: IntArray
    term_exp: IntArray
    term_slot: IntArray
    n_raw: int
    # chains: raw polynomial slots, Padé parameter, state offsets
    chain_num: IntArray
    chain_den: IntArray
    chain_pade: IntArray
    chain_offset: IntArray
    chain_size: IntArray
    chain_num_length: IntArray
    chain_den_length: IntArray
    # branches (chains 1..) feeding the main chain: input index and chain index
    branch_chain: IntArray
    branch_input: IntArray
    dense_rows: IntArray

    @property
    def n_parameters(self) -> int:
        """Number of parameters ``n_p``."""
        return len(self.parameter_names)

    def active_table(self, needed: tuple[str, ...] | None = None) -> IntArray:
        """Parameters whose gradients :func:`evaluate_coefficients` computes, per chain.

        Shape ``(n_chain, 3, n_p)``: for each chain the parameters of its numerator,
        of its denominator and of both, restricted to ``needed`` (default: all), each
        list padded with -1. A chain's Padé parameter is always listed (its gradient
        entries are accumulated and so must be reset every call).
        """
        names = self.parameter_names
        wanted = set(range(len(names))) if needed is None else {names.index(n) for n in needed}
        slot_params: dict[int, set[int]] = {}
        for t in range(self.term_coef.shape[0]):
            variables = {int(j) for j in self.term_var[t] if j >= 0}
            slot_params.setdefault(int(self.term_slot[t]), set()).update(variables)
        n_chain = self.chain_num.shape[0]
        table = np.full((n_chain, 3, len(names)), -1, dtype=np.int64)
        for c in range(n_chain):
            sets = []
            for start, length in (self.chain_num[c], self.chain_den[c]):
                used: set[int] = set()
                for slot in range(int(start), int(start + length)):
                    used |= slot_params.get(slot, set())
                used &= wanted
                if self.chain_pade[c] >= 0:
                    used.add(int(self.chain_pade[c]))
                sets.append(used)
            sets.append(sets[0] | sets[1])
            for which, used in enumerate(sets):
                ordered = sorted(used)
                table[c, which, : len(ordered)] = ordered
        return table

    def kernel(self, needed: tuple[str, ...] | None = None) -> ModelKernel:
        """A fresh :class:`ModelKernel` (tables shared, scratch and outputs new).

        ``needed``: the parameters whose gradients the filter reads (default: all;
        ``()`` for filters that need values only, such as the unscented ones).
        """
        n_p = self.n_parameters
        n_chain = self.chain_num.shape[0]
        longest = int(max(self.chain_den_length.max(), self.chain_num_length.max()))
        return ModelKernel(
            self.term_coef,
            self.term_var,
            self.term_exp,
            self.term_slot,
            self.chain_num,
            self.chain_den,
            self.chain_pade,
            self.chain_offset,
            self.chain_size,
            self.chain_num_length,
            self.chain_den_length,
            self.branch_chain,
            self.branch_input,
            self.active_table(needed),
            needed is None or len(needed) > 0,
            np.zeros(self.n_raw),
            np.zeros((self.n_raw, n_p)),
            np.zeros((n_chain, longest)),
            np.zeros((n_chain, longest, n_p)),
            np.zeros((n_chain, longest)),
            np.zeros((n_chain, longest, n_p)),
            np.zeros((2, self.delay_order + 1)),
            np.zeros((2, self.delay_order + 1)),
            np.zeros(self.n_states),
            np.zeros((self.n_states, n_p)),
            np.zeros(self.n_states),
            np.zeros((self.n_states, n_p)),
            np.zeros(n_chain),
            np.zeros((n_chain, n_p)),
        )

    def evaluate(self, p: FloatArray, x: FloatArray, inputs: FloatArray) -> ModelEvaluation:
        """``f``, ``g`` and Jacobians at parameters ``p``, states ``x`` and ``inputs``.

        ``p`` in :attr:`parameter_names` order (``tau_f*`` in the ``tau_f`` slot),
        ``x`` the canonical states, ``inputs`` in :attr:`input_names` order. Meant for
        checks and plots; the filters call the compiled kernels directly.
        """
        p = np.ascontiguousarray(p, dtype=np.float64)
        x = np.ascontiguousarray(x, dtype=np.float64)
        inputs = np.ascontiguousarray(inputs, dtype=np.float64)
        from manualcontrol.estimators.members._internal_model_kernels import (
            evaluate_coefficients,
            model_f,
            model_g,
        )

        kernel = self.kernel()
        evaluate_coefficients(p, kernel)
        n, n_p = self.n_states, self.n_parameters
        f = np.zeros(n)
        F = np.zeros((n, n))
        dfdp = np.zeros((n, n_p))
        dgdx = np.zeros(n)
        dgdp = np.zeros(n_p)
        model_f(x, inputs, kernel, f, F, dfdp, True)
        g = model_g(x, inputs, kernel, dgdx, dgdp, True)
        return ModelEvaluation(f, F, dfdp, float(g), dgdx, dgdp)


# --------------------------------------------------------------- polynomial recovery


def _coefficient_polynomials(model: PilotModel, values: dict[str, FloatArray]) -> list[FloatArray]:
    """The raw coefficient arrays of the one channel, in slot order.

    Slots: post-delay numerator, post-delay denominator, then numerator and
    denominator of each branch, each an array ``(..., length)``.
    """
    (channel,) = model.channels(values)
    arrays = [channel.num, channel.den]
    for branch in channel.branches:
        arrays.extend((branch.num, branch.den))
    shape = np.broadcast_shapes(*(np.shape(v) for v in values.values()))
    return [np.broadcast_to(np.asarray(a, dtype=np.float64), (*shape, a.shape[-1])) for a in arrays]


def _recover_monomials(
    model: PilotModel, names: tuple[str, ...], degree: int
) -> list[list[tuple[float, tuple[int, ...]]]] | None:
    """Monomials of every raw coefficient, or None if not polynomial of that degree."""
    nodes = np.arange(degree + 1, dtype=np.float64)
    n_p = len(names)
    grids = np.meshgrid(*([nodes] * n_p), indexing="ij")
    values = {name: grid.ravel() for name, grid in zip(names, grids, strict=True)}
    raw = _coefficient_polynomials(model, values)
    inverse = np.linalg.inv(np.vander(nodes, increasing=True))  # exact: dyadic entries
    monomials: list[list[tuple[float, tuple[int, ...]]]] = []
    for array in raw:
        for j in range(array.shape[-1]):
            tensor = array[..., j].reshape((degree + 1,) * n_p)
            for axis in range(n_p):
                tensor = np.moveaxis(np.tensordot(inverse, tensor, axes=(1, axis)), 0, axis)
            scale = max(float(np.abs(tensor).max()), 1.0)
            terms = [
                (float(tensor[index]), tuple(int(e) for e in index))
                for index in zip(*np.nonzero(np.abs(tensor) > 1e-12 * scale), strict=True)
            ]
            monomials.append(terms)
    # verify at random points
    rng = np.random.default_rng(12345)
    points = {name: rng.uniform(0.3, 3.0, _CHECK_POINTS) for name in names}
    check = _coefficient_polynomials(model, points)
    slot = 0
    for array in check:
        for j in range(array.shape[-1]):
            expected = array[..., j]
            got = np.zeros(_CHECK_POINTS)
            for coef, exponents in monomials[slot]:
                term = np.full(_CHECK_POINTS, coef)
                for name, e in zip(names, exponents, strict=True):
                    term = term * points[name] ** e
                got += term
            if not np.allclose(got, expected, rtol=1e-11, atol=1e-12):
                return None
            slot += 1
    return monomials


def build_internal_model(
    model: str | PilotModel, delay_order: int = 3, *, pursuit: bool = False
) -> InternalModel:
    """Build the internal model of a pilot structure.

    Parameters
    ----------
    model
        A single-channel :class:`~manualcontrol.pilots.models.PilotModel` or its name:
        ``"precision"``, ``"preview"`` (far view only), ``"gain-delay"``,
        ``"schiess-roland"``.
    delay_order
        Padé order (>= 1) of the model delay and of the anticipation delay ``tau_f*``;
        3 as in Popovici et al. and the thesis. A branch fed by ``ft_far`` is fed the
        anticipated target through ``exp(-tau_f* s)`` (thesis eq. 26) unless
        ``pursuit`` (below). ``0`` leaves both delays out of the model: its inputs are
        then the perceptions already delayed by the model delay (and ``ft_ahead`` by
        ``tau_f*`` besides), for filters that read them from delay lines (the delays
        commute with the model's linear branches); the delay parameters then enter no
        coefficient.
    pursuit
        A pursuit display shows the current target and nothing ahead (the preview
        model with ``tau_f = 0``, van der El's pursuit case), so the branch reads
        ``ft`` itself, without the anticipation delay, and ``tau_f`` enters nowhere.

    Raises
    ------
    ValueError
        For a model with more than one channel (the preview model's near view), a
        perception other than ``e``, ``y`` or ``ft_far``, or coefficients that are not
        polynomials of degree <= 3 in each parameter.

    """
    model = make_model(model)
    delay_order = check_int("delay_order", delay_order, minimum=0)
    names = model.parameter_names
    probe = {name: np.array(1.0) for name in names}
    channels = model.channels(probe)
    if len(channels) != 1:
        raise ValueError(
            f"the internal model supports single-channel pilot models; {model!r} has "
            f"{len(channels)} channels (the preview model's near view is not supported)"
        )
    (channel,) = channels
    for branch in channel.branches:
        check_choice("pilot perception", branch.signal, tuple(INPUT_SIGNALS))
    anticipated = any(branch.signal == "ft_far" for branch in channel.branches)
    monomials = None
    for degree in range(1, _MAX_DEGREE + 1):
        monomials = _recover_monomials(model, names, degree)
        if monomials is not None:
            break
    if monomials is None:
        raise ValueError(
            f"the channel coefficients of {model!r} are not polynomials of degree <= "
            f"{_MAX_DEGREE} in each parameter"
        )
    # raw slot layout
    raw_arrays = _coefficient_polynomials(model, probe)
    lengths = [array.shape[-1] for array in raw_arrays]
    starts = np.concatenate(([0], np.cumsum(lengths)))
    n_raw = int(starts[-1])

    term_coef, term_var, term_exp, term_slot = [], [], [], []
    for slot, terms in enumerate(monomials):
        for coef, exponents in terms:
            variables = [(j, e) for j, e in enumerate(exponents) if e > 0]
            term_coef.append(coef)
            term_slot.append(slot)
            padded = variables + [(-1, 0)] * (len(names) - len(variables))
            term_var.append([j for j, _ in padded])
            term_exp.append([e for _, e in padded])

    # which parameters appear where
    slot_owner = np.repeat(np.arange(len(raw_arrays)), lengths)  # raw array index per slot
    used_in: dict[str, set[int]] = {name: set() for name in names}
    for slot, terms in enumerate(monomials):
        for _, exponents in terms:
            for j, e in enumerate(exponents):
                if e > 0:
                    used_in[names[j]].add(int(slot_owner[slot]))
    delay = model.delay_parameter
    gains = tuple(
        name
        for name in names
        if used_in[name] == {0} and name not in (delay, ANTICIPATED_PARAMETER)
    )
    main_arrays = {0, 1}  # the main chain's numerator and denominator
    branch_only = tuple(
        name
        for name in names
        if name == ANTICIPATED_PARAMETER
        or (used_in[name] and not used_in[name] & main_arrays and name != delay)
    )

    # chains: main (post x Pade(delay)), then branches
    pade_degree = delay_order
    chain_num = [0]
    chain_den = [1]
    chain_pade = [names.index(delay) if pade_degree else -1]
    inputs: list[str] = []
    branch_chain: list[int] = []
    branch_input: list[int] = []
    for b, branch in enumerate(channel.branches):
        signal = INPUT_SIGNALS[branch.signal]
        anticipating = branch.signal == "ft_far" and not pursuit
        if branch.signal == "ft_far" and pursuit:
            signal = "ft"
        if signal not in inputs:
            inputs.append(signal)
        chain_num.append(2 + 2 * b)
        chain_den.append(3 + 2 * b)
        anticipates = anticipating and pade_degree > 0
        chain_pade.append(names.index(ANTICIPATED_PARAMETER) if anticipates else -1)
        branch_chain.append(b + 1)
        branch_input.append(inputs.index(signal))
    if anticipated and not pursuit and ANTICIPATED_PARAMETER not in names:
        raise ValueError(f"{model!r} reads ft_far but has no parameter {ANTICIPATED_PARAMETER}")
    num_length, den_length, sizes = [], [], []
    for num_slot, den_slot, pade_index in zip(chain_num, chain_den, chain_pade, strict=True):
        extra = pade_degree if pade_index >= 0 else 0
        num_length.append(lengths[num_slot] + extra)
        den_length.append(lengths[den_slot] + extra)
        sizes.append(lengths[den_slot] + extra - 1)
        if num_length[-1] > den_length[-1]:
            raise ValueError(f"{model!r} has an improper chain (numerator above denominator)")
    offsets = np.concatenate(([0], np.cumsum(sizes)))[:-1]
    n_states = int(sum(sizes))
    dense = [int(offsets[c] + sizes[c] - 1) for c in range(len(sizes)) if sizes[c] > 0]

    def ints(values: list[int]) -> IntArray:
        return np.asarray(values, dtype=np.int64).reshape(-1)

    raw_start = ints(list(starts[:-1]))
    return InternalModel(
        model=model,
        delay_order=delay_order,
        parameter_names=names,
        input_names=tuple(inputs),
        gain_parameters=gains,
        branch_parameters=branch_only,
        n_states=n_states,
        input_states=tuple(int(offsets[c] + sizes[c] - 1) for c in range(len(sizes)) if sizes[c]),
        term_coef=np.asarray(term_coef, dtype=np.float64),
        term_var=np.asarray(term_var, dtype=np.int64).reshape(len(term_coef), len(names)),
        term_exp=np.asarray(term_exp, dtype=np.int64).reshape(len(term_coef), len(names)),
        term_slot=ints(term_slot),
        n_raw=n_raw,
        chain_num=np.stack([raw_start[chain_num], ints([lengths[s] for s in chain_num])], 1),
        chain_den=np.stack([raw_start[chain_den], ints([lengths[s] for s in chain_den])], 1),
        chain_pade=ints(chain_pade),
        chain_offset=ints(list(offsets)),
        chain_size=ints(sizes),
        chain_num_length=ints(num_length),
        chain_den_length=ints(den_length),
        branch_chain=ints(branch_chain),
        branch_input=ints(branch_input),
        dense_rows=ints(dense),
    )


# ------------------------------------------------------------------ compiled kernels


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "_pade_jet",
    "_chain_polynomial",
    "evaluate_coefficients",
    "model_f",
    "model_g",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.members._internal_model_kernels", _KERNELS
)
