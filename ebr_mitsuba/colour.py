"""Colour constants of the toolkit (linear RGB, Rec. 709 / sRGB primaries).

==================  =========================  ==================================================
name                value                      use
==================  =========================  ==================================================
LUMINANCE_WEIGHTS   (0.2126, 0.7152, 0.0722)   luminance Y = w · (R, G, B) of linear RGB (BT.709)
LUMINANCE           the same, a float64 array  ``image @ LUMINANCE``: (…, 3) → (…)
==================  =========================  ==================================================

Every luminance in the toolkit (exemplar selection, quad-tree splits, lobe energies, environment
normalisation, the BRDF's sampling weights) uses these weights; the Dr.Jit code reads the tuple
(:func:`ebr_mitsuba.brdf.luminance`).
"""

from __future__ import annotations

import numpy as np

LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)
LUMINANCE = np.array(LUMINANCE_WEIGHTS)


__all__ = ["LUMINANCE", "LUMINANCE_WEIGHTS"]
