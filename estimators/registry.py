"""The estimator family by name: what the bench, the CLI and suite files can name.

:data:`MEMBERS` lists the family in one place: each :class:`EstimatorEntry` has its name
(the ``estimator`` column of results, ``[batch.estimator] name = ...`` in suite files,
``manualcontrol identify --estimator NAME``), a one-line summary (``manualcontrol
estimators``), the paper it follows, and how to build it from a plain settings table
(the suite file's keys). A member's module is imported when the member is first built,
not when the registry is read, so listing or naming the family costs no import of
its filters.

The offline twins are derived at lookup, never registered: every smoothable member
``name`` has ``"<name>-smoothed"`` (its run smoothed over the whole recording,
:mod:`~manualcontrol.estimators.offline.smoothed_estimator`), and every smoothable member on a pilot
model has ``"<name>-cv"`` (smoothed at the process-noise scale chosen by
cross-validation, :mod:`~manualcontrol.estimators.offline.cross_validation`). So a member
always has its twins, whatever was imported first. :data:`ESTIMATORS` is the whole
family, twins included; :func:`register` adds a member (a user's own estimator).
:func:`make_estimator` builds one from ``{"name": ..., **settings}``, validating the
settings through the estimator's own settings class.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from dataclasses import dataclass
from typing import Any

from manualcontrol.envs._validation import check_choice

__all__ = [
    "CROSS_VALIDATED_SUFFIX",
    "ESTIMATORS",
    "MEMBERS",
    "SMOOTHED_SUFFIX",
    "EstimatorEntry",
    "make_estimator",
    "register",
]

#: Suffix of the smoothed twins' names.
SMOOTHED_SUFFIX = "-smoothed"
#: Suffix of the cross-validated twins' names.
CROSS_VALIDATED_SUFFIX = "-cv"


@dataclass(frozen=True)
class EstimatorEntry:
    """One member of the family: how to name, describe and build it.

    ``resimulate(result, recording)``, when given, is the member's own model output
    from the recorded inputs with the identified traces (for members whose model is not
    a pilot structure; :func:`~manualcontrol.estimators.analysis.metrics.resimulate` uses it).
    ``pilot_model``: the member runs on a pilot model structure named by its ``model``
    setting (``precision``, ``preview``), as ``manualcontrol identify --model`` sets it.
    ``smoothable``: its ``estimate`` takes ``smooth=True`` (a fixed-interval smoother
    applies), so it has a ``-smoothed`` twin (and, on a pilot model, a ``-cv`` twin).
    ``base`` and ``twin``: for a derived twin, the online member whose filter it runs
    and how its result is made offline (``"smoothed"``, ``"cross-validated"``).
    """

    name: str
    summary: str
    reference: str
    build: Callable[[Mapping[str, Any]], Any]
    resimulate: Callable[[Any, Any], Any] | None = None
    pilot_model: bool = False
    smoothable: bool = True
    base: str | None = None
    twin: str | None = None


def _imported(module: str, attribute: str) -> Callable[..., Any]:
    """A function that imports ``module`` on its first call and calls its ``attribute``.

    The registry names its members' builders by module, so that reading the family
    (``manualcontrol estimators``, a suite file's check) imports none of the filters.
    """

    def call(*args: Any) -> Any:
        return getattr(importlib.import_module(module), attribute)(*args)

    call.__qualname__ = call.__name__ = f"{module}.{attribute}"
    return call


def _member(module: str, cls: str) -> Callable[[Mapping[str, Any]], Any]:
    """The build function of a member class (``cls.from_settings(settings)``)."""

    def build(settings: Mapping[str, Any]) -> Any:
        return getattr(importlib.import_module(module), cls).from_settings(settings)

    build.__qualname__ = build.__name__ = f"{module}.{cls}.from_settings"
    return build


_PACKAGE = "manualcontrol.estimators"

#: The online and offline members, in the order ``manualcontrol estimators`` lists them.
MEMBERS: tuple[EstimatorEntry, ...] = (
    EstimatorEntry(
        name="dekf",
        summary="dual extended Kalman filter: states + gains, and the other parameters "
        "(total derivative), on the precision or preview internal model",
        reference="Popovici et al. 2017; Vertregt 2020",
        build=_member(f"{_PACKAGE}.members.dekf", "DEKF"),
        pilot_model=True,
    ),
    EstimatorEntry(
        name="schiess-roland",
        summary="joint EKF on the delayed lead-lag pilot with a second-order remnant: 13 "
        "states, exact hereditary delay, stick and plant output measured, adaptive noise",
        reference="Schiess & Roland 1975",
        build=_member(f"{_PACKAGE}.members.schiess_roland", "SchiessRoland"),
    ),
    EstimatorEntry(
        name="rdi",
        summary="recursive delay identifier: EKF over ARMAX coefficients and a fractional, "
        "time-varying delay (bicubic interpolation, decimation, sign constraints, RTS)",
        reference="Boer & Kenyon 1998",
        build=_member(f"{_PACKAGE}.members.rdi", "RDI"),
        resimulate=_imported(f"{_PACKAGE}.members.rdi", "resimulate"),
    ),
    EstimatorEntry(
        name="rml",
        summary="recursive maximum likelihood over a bank of Kalman filters: exact delays, "
        "a remnant shaping filter whose intensity is learned (survives remnant)",
        reference="Ljung & Söderström 1983; Levison et al. 1969",
        build=_member(f"{_PACKAGE}.members.rml", "RML"),
        pilot_model=True,
    ),
    EstimatorEntry(
        name="sigmoid-fit",
        summary="output-error fit of a pilot whose parameters change along one shared "
        "sigmoid (offline; the scheduling-function approach)",
        reference="Zaal 2016; thesis Part II eq. 4.2",
        build=_member(f"{_PACKAGE}.offline.schedule_fit", "SigmoidFitEstimator"),
        pilot_model=True,
        smoothable=False,
    ),
    EstimatorEntry(
        name="joint-ukf",
        summary="joint unscented Kalman filter: pilot states and parameters in one "
        "augmented filter, on the precision or preview internal model",
        reference="Zhao et al. 2019 (Alg. 1-2); future work of Popovici 2017, Vertregt 2020",
        build=_member(f"{_PACKAGE}.members.ukf", "JointUKF"),
        pilot_model=True,
    ),
    EstimatorEntry(
        name="dual-ukf",
        summary="dual unscented Kalman filter: the DEKF's state and parameter filters "
        "with sigma points instead of Jacobians",
        reference="Wan & van der Merwe 2001; future work of Popovici 2017, Vertregt 2020",
        build=_member(f"{_PACKAGE}.members.ukf", "DualUKF"),
        pilot_model=True,
    ),
    EstimatorEntry(
        name="zhao-ukf",
        summary="UKF (cubature points) on the cybernetic driver model, parameters as random "
        "walks, Algorithm 3 tuning (presets ukf1, ukf2)",
        reference="Zhao et al. 2019",
        build=_member(f"{_PACKAGE}.members.zhao_ukf", "ZhaoUKF"),
    ),
    EstimatorEntry(
        name="zhao-multi-ukf",
        summary="multi-UKF: a slow (ukf1) and a fast (ukf2) driver-model UKF, fused by "
        "gated shrinkage of their disagreement with re-centring of the slow one",
        reference="Zhao et al. 2019 Sec. 4.2 (fusion rule ours)",
        build=_member(f"{_PACKAGE}.members.zhao_ukf", "MultiUKF"),
        smoothable=False,  # the fusion is causal; smooth the members instead
    ),
)


def _smoothed_twin(base: EstimatorEntry) -> EstimatorEntry:
    wrap = _imported(f"{_PACKAGE}.offline.smoothed_estimator", "SmoothedEstimator")
    return EstimatorEntry(
        name=f"{base.name}{SMOOTHED_SUFFIX}",
        summary=f"{base.name}, smoothed over the whole run (offline; Rauch-Tung-Striebel)",
        reference=base.reference,
        build=lambda settings: wrap(base.build(settings)),
        resimulate=base.resimulate,
        pilot_model=base.pilot_model,
        smoothable=False,
        base=base.name,
        twin="smoothed",
    )


def _cross_validated_twin(base: EstimatorEntry) -> EstimatorEntry:
    wrap = _imported(f"{_PACKAGE}.offline.cross_validation", "build_cross_validated")
    return EstimatorEntry(
        name=f"{base.name}{CROSS_VALIDATED_SUFFIX}",
        summary=f"{base.name}, smoothed at the process-noise scale that predicts held-out "
        "stretches best (offline; cross-validation in the forcing band)",
        reference=base.reference,
        build=lambda settings: wrap(base.build, settings),
        resimulate=base.resimulate,
        pilot_model=True,
        smoothable=False,
        base=base.name,
        twin="cross-validated",
    )


class _Family(MutableMapping[str, EstimatorEntry]):
    """The members by name, with each one's offline twins derived from it at lookup."""

    def __init__(self, members: tuple[EstimatorEntry, ...]) -> None:
        self._members = {entry.name: entry for entry in members}
        # each twin with the member it was derived from: a member replaced gets fresh twins
        self._twins: dict[str, tuple[EstimatorEntry, EstimatorEntry]] = {}

    def _twin(self, name: str) -> EstimatorEntry | None:
        for suffix, derive, wanted in (
            (SMOOTHED_SUFFIX, _smoothed_twin, lambda base: base.smoothable),
            (
                CROSS_VALIDATED_SUFFIX,
                _cross_validated_twin,
                lambda base: base.smoothable and base.pilot_model,
            ),
        ):
            if name.endswith(suffix):
                base = self._members.get(name[: -len(suffix)])
                if base is None or base.base is not None or not wanted(base):
                    return None
                derived_from, twin = self._twins.get(name, (None, None))
                if derived_from is not base:
                    twin = derive(base)
                    self._twins[name] = (base, twin)
                return twin
        return None

    def __getitem__(self, name: str) -> EstimatorEntry:
        entry = self._members.get(name)
        if entry is None:
            entry = self._twin(name) if isinstance(name, str) else None
        if entry is None:
            raise KeyError(name)
        return entry

    def __iter__(self) -> Iterator[str]:
        members = [entry for entry in self._members.values() if entry.base is None]
        yield from self._members
        for entry in members:
            if entry.smoothable and f"{entry.name}{SMOOTHED_SUFFIX}" not in self._members:
                yield f"{entry.name}{SMOOTHED_SUFFIX}"
        for entry in members:
            twin = f"{entry.name}{CROSS_VALIDATED_SUFFIX}"
            if entry.smoothable and entry.pilot_model and twin not in self._members:
                yield twin

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __setitem__(self, name: str, entry: EstimatorEntry) -> None:
        self._members[name] = entry

    def __delitem__(self, name: str) -> None:
        del self._members[name]

    def __repr__(self) -> str:
        return f"<the estimator family: {', '.join(self)}>"


#: Every estimator by name: the members and their derived twins.
ESTIMATORS: MutableMapping[str, EstimatorEntry] = _Family(MEMBERS)


def register(entry: EstimatorEntry) -> EstimatorEntry:
    """Add ``entry`` to the family (a name registers once; a smoothable one gets twins)."""
    if entry.name in ESTIMATORS and ESTIMATORS[entry.name] is not entry:
        raise ValueError(f"an estimator named {entry.name!r} is registered already")
    ESTIMATORS[entry.name] = entry
    return entry


def make_estimator(spec: Mapping[str, Any]) -> Any:
    """An estimator from ``{"name": ..., **settings}`` (settings as in suite files)."""
    if not isinstance(spec, Mapping):
        raise TypeError(f"estimator spec must be a table with a name, got {spec!r}")
    spec = dict(spec)
    name = check_choice("estimator name", spec.pop("name", None), tuple(ESTIMATORS))
    return ESTIMATORS[name].build(spec)
