"""The family's offline members: each filter's results smoothed over the whole run.

Offline analysis may use the whole run (:mod:`~manualcontrol.estimators.smoothing`):
``estimate(recording, smooth=True)``. For the bench, whose rows are keyed by estimator
name, every smoothable member registered when this module is imported gets an offline twin
``"<name>-smoothed"`` with the same settings, whose :meth:`SmoothedEstimator.estimate`
returns the smoothed result (``result.smoothed`` is True, and the bench's report ranks
those apart from the online filters). A smoothed estimate needs the samples after it,
so the twins have no online ``update``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.protocol import EstimationResult
from manualcontrol.estimators.registry import ESTIMATORS, EstimatorEntry, register

__all__ = ["SUFFIX", "SmoothedEstimator", "register_smoothed"]

#: Suffix of the offline twins' names.
SUFFIX = "-smoothed"


class SmoothedEstimator:
    """An estimator whose whole-run results are smoothed (see the module docstring).

    Parameters
    ----------
    filter
        The online estimator (anything with ``estimate(recording, smooth=True)``).
    """

    def __init__(self, filter: Any) -> None:
        self._filter = filter

    @property
    def filter(self) -> Any:
        """The online estimator whose results are smoothed."""
        return self._filter

    @property
    def settings(self) -> Any:
        """The online estimator's settings."""
        return self._filter.settings

    def estimate(self, recording: Recording, **options: Any) -> EstimationResult:
        """The filter's run over ``recording``, smoothed (``options`` as the filter's)."""
        if "smooth" in options:
            raise TypeError("a smoothed estimator always smooths; do not pass smooth=")
        return self._filter.estimate(recording, smooth=True, **options)

    def reset(self, *args: Any, **kwargs: Any) -> None:
        """Not available: a smoothed estimate needs the whole run."""
        raise TypeError(
            "a smoothed estimator works on whole recordings (estimate); for online "
            "estimation use the filter itself"
        )

    update = reset

    def __repr__(self) -> str:
        return f"SmoothedEstimator({self._filter!r})"


def register_smoothed(name: str) -> EstimatorEntry:
    """Register ``name + SUFFIX``: the registered estimator ``name``, smoothed."""
    base = ESTIMATORS[name]
    if not base.smoothable:
        raise ValueError(f"{name!r} has no fixed-interval smoother (smoothable is False)")

    def build(settings: Mapping[str, Any]) -> SmoothedEstimator:
        return SmoothedEstimator(base.build(settings))

    return register(
        EstimatorEntry(
            name=f"{name}{SUFFIX}",
            summary=f"{name}, smoothed over the whole run (offline; Rauch-Tung-Striebel)",
            reference=base.reference,
            build=build,
            resimulate=base.resimulate,
            pilot_model=base.pilot_model,
            smoothable=False,
        )
    )


for _name in [name for name, entry in ESTIMATORS.items() if entry.smoothable]:
    if f"{_name}{SUFFIX}" not in ESTIMATORS:
        register_smoothed(_name)
