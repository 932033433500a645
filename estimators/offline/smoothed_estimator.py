"""The family's offline members: each filter's results smoothed over the whole run.

Offline analysis may use the whole run (:mod:`~manualcontrol.estimators.offline.smoothing`):
``estimate(recording, smooth=True)``. For the bench, whose rows are keyed by estimator
name, every smoothable member has an offline twin ``"<name>-smoothed"`` with the same
settings (derived in :mod:`~manualcontrol.estimators.registry`), whose
:meth:`SmoothedEstimator.estimate` returns the smoothed result (``result.smoothed`` is
True, and the bench's report ranks those apart from the online filters). A smoothed
estimate needs the samples after it, so the twins have no online ``update``.
"""

from __future__ import annotations

from typing import Any

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.protocol import EstimationResult

__all__ = ["SmoothedEstimator"]


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
