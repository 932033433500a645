"""The estimator family by name: what the bench, the CLI and suite files can name.

Each member registers an :class:`EstimatorEntry`: its name (the ``estimator`` column of
results, ``[batch.estimator] name = ...`` in suite files, ``manualcontrol identify
--estimator NAME``), a one-line summary (``manualcontrol estimators``), the paper it
follows, and how to build it from a plain settings table (the suite file's keys).
:func:`make_estimator` builds one from ``{"name": ..., **settings}``, validating the
settings through the estimator's own settings class.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from manualcontrol.envs._validation import check_choice

__all__ = ["ESTIMATORS", "EstimatorEntry", "make_estimator", "register"]


@dataclass(frozen=True)
class EstimatorEntry:
    """One member of the family: how to name, describe and build it.

    ``resimulate(result, recording)``, when given, is the member's own model output
    from the recorded inputs with the identified traces (for members whose model is not
    a pilot structure; :func:`~manualcontrol.estimators.metrics.resimulate` uses it).
    ``pilot_model``: the member runs on a pilot model structure named by its ``model``
    setting (``precision``, ``preview``), as ``manualcontrol identify --model`` sets it.
    ``smoothable``: its ``estimate`` takes ``smooth=True`` (a fixed-interval smoother
    applies), so :mod:`~manualcontrol.estimators.smoothed` registers its offline twin.
    """

    name: str
    summary: str
    reference: str
    build: Callable[[Mapping[str, Any]], Any]
    resimulate: Callable[[Any, Any], Any] | None = None
    pilot_model: bool = False
    smoothable: bool = True


#: Registered estimators, by name.
ESTIMATORS: dict[str, EstimatorEntry] = {}


def register(entry: EstimatorEntry) -> EstimatorEntry:
    """Add ``entry`` to :data:`ESTIMATORS` (a name registers once)."""
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


def _dekf(settings: Mapping[str, Any]) -> Any:
    from manualcontrol.estimators.dekf import DEKF, DEKFSettings

    return DEKF(DEKFSettings.from_dict(dict(settings)))


register(
    EstimatorEntry(
        name="dekf",
        summary="dual extended Kalman filter: states + gains, and the other parameters "
        "(total derivative), on the precision or preview internal model",
        reference="Popovici et al. 2017; Vertregt 2020",
        build=_dekf,
        pilot_model=True,
    )
)


def _schiess_roland(settings: Mapping[str, Any]) -> Any:
    from manualcontrol.estimators.schiess_roland import SchiessRoland, SchiessRolandSettings

    return SchiessRoland(SchiessRolandSettings.from_dict(dict(settings)))


register(
    EstimatorEntry(
        name="schiess-roland",
        summary="joint EKF on the delayed lead-lag pilot with a second-order remnant: 13 "
        "states, exact hereditary delay, stick and plant output measured, adaptive noise",
        reference="Schiess & Roland 1975",
        build=_schiess_roland,
    )
)
