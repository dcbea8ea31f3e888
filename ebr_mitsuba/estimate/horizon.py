"""Lobes at the horizon: lighting that a flat sample's photos barely see (``ebr estimate
--drop-horizon-lobes``, off by default).

The photos of a flash / no-flash capture see the environment through the flat sample: its
no-flash shot is the albedo times the irradiance ∫ L(ω) (n·ω)⁺ dω plus the sample's reflection of
the sky towards a camera straight above. A lobe whose axis lies at the horizon (its axis' z
under :data:`HORIZON_Z`, an elevation under about 3°) lights the sample at grazing incidence, so
its amplitude changes the photos little and
the estimate's SG extraction sets it almost freely: in 13 of the 16 estimates below (shipped
model) such lobes sit at z = 0.00–0.05 and hold 8–62 % of the lobes' energy, but only 2–41 % of
the sample's irradiance. An object standing on the sample faces the horizon, so an inserted
sphere (``ebr insert``) takes that free energy at full strength on its side.

:func:`drop_horizon_lobes` drops those lobes and scales the others per channel so that the
sample's irradiance (normal +z, :meth:`~ebr_mitsuba.sgenv.SGEnvironment.irradiance`) is the one
the full estimate had — what the photos measured stays, what they could not measure goes. It
is skipped when every lobe is at the horizon (nothing would be left to scale) and when none is.

Tried on 16 insertions not in ``ebr bench insert`` (four ``ebr capture`` syntheses of procedural
materials under procedural maps, ``wood:2``, ``tiles:3``, ``leather:4``, ``marble:1`` under maps 5,
6, 9, 11, and the first twelve captures of ``configs/data_real_val.toml``, training materials
under training HDR maps; a diffuse sphere, 128², 256 spp, composited; the ratio of its RMSE
against the truth's to the truth-vs-truth noise floor): geometric mean ratio 6.37 with the lobes
kept as estimated, 4.45 with those under z = 0.05 dropped, lower in 10 of the 16 and higher in 2
(a procedural low sun at 10° elevation, which the estimate had put at the horizon: 7.6 → 12.3;
an HDR sunset: 7.4 → 7.9). Thresholds z = 0.1 / 0.15 / 0.2 gave 4.59 / 4.72 / 4.95 (higher in 4 /
3 / 5). Lifting the lobes to z = 0.1 / 0.2 / 0.3 instead, each keeping its own irradiance on the
sample, gave 5.40 / 4.93 / 4.67. It did not carry over to the benchmark's own cases
(``docs/bench/insert.md``, which measures both): on its six synthetic insertions the geometric
mean ratio went 15.46 → 15.00 (lower in 3 of 6, one of them a tile set with no lobe at the
horizon, equal to four digits), on the eight test-split captures 5.87 → 6.05
(lower in 5 of 8, higher by more in the other 3) — real HDR maps often do hold light at the
horizon. So it is an option, off by default.
"""

from __future__ import annotations

import numpy as np

from ..colour import LUMINANCE
from ..sgenv import SGEnvironment

#: Lobes whose axis has z below this (elevation ≈ 2.9°) count as at the horizon.
HORIZON_Z = 0.05


def drop_horizon_lobes(env: SGEnvironment, min_z: float = HORIZON_Z) -> tuple[SGEnvironment, dict]:
    """``env`` without its lobes at the horizon (axis z < ``min_z``), the others scaled per channel
    to keep the irradiance on the sample plane (module docstring), and the record written to
    ``estimate.json`` (``applied``, ``dropped``, ``min_z``, the ``gain`` per channel and the
    dropped lobes' ``irradiance_share``, luminance)."""
    z = np.asarray(env.axis, np.float64)[:, 2]
    low = z < min_z
    record: dict = {"applied": False, "dropped": 0, "min_z": float(min_z)}
    if not low.any() or low.all():
        return env, record
    per_lobe = env.lobe_irradiance()
    amp = env.amplitude.astype(np.float64)
    before = per_lobe @ amp
    after = per_lobe[~low] @ amp[~low]
    gain = np.where(after > 0, before / np.maximum(after, 1e-30), 1.0)
    share = float((before - after) @ LUMINANCE / max(float(before @ LUMINANCE), 1e-30))
    record.update(
        applied=True,
        dropped=int(low.sum()),
        gain=[float(g) for g in gain],
        irradiance_share=share,
    )
    kept = env.amplitude[~low] * gain[None, :].astype(np.float32)
    return SGEnvironment(env.axis[~low], env.sharpness[~low], kept), record
