"""Per-map errors of an estimate against ground truth: :func:`ebr_mitsuba.metrics.map_rmse`
(``docs/conventions.md``, "Metrics"), the one definition every command reports.

RMSE per map over all pixels and channels, normals encoded as (n + 1)/2, roughness one channel,
and their mean (as the EBREnv lab reports). Ground truth of another size is area-resampled to
the estimate's grid first.
"""

from __future__ import annotations

from ..metrics import map_rmse

__all__ = ["map_rmse"]
