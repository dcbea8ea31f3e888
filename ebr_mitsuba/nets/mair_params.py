"""``python -m ebr_mitsuba.nets.mair_params``: parameter counts of every MAIR preset and fusion.

Prints one line per preset (``tiny``, ``small``, ``paper``) and fusion (``attention``, ``mean``)
with the trainable parameters of each stage module of :class:`~.mair.MAIRModel` and the total,
at the default ``num_sgs`` = 3 (the table of ``docs/mair.md``).
"""

from __future__ import annotations

from .mair import stage_parameter_counts
from .mair_config import FUSIONS, MAIR_SIZE_PRESETS, MAIRConfig


def main() -> None:
    for preset in MAIR_SIZE_PRESETS:
        for fusion in FUSIONS:
            counts = stage_parameter_counts(MAIRConfig(size=preset, fusion=fusion))
            print(f"{preset:6s} {fusion:9s} " + "  ".join(f"{k}={v}" for k, v in counts.items()))


if __name__ == "__main__":
    main()
