"""Numeric floors and clamps of the BRDF, shared by its three implementations.

The Dr.Jit BRDF (:mod:`ebr_mitsuba.brdf`) and its torch mirror (:mod:`ebr_mitsuba.nets.torch_brdf`)
read these values from here, so that the test comparing them compares the same function
(``docs/conventions.md``, "BRDF"); the float64 numpy reference (:mod:`ebr_mitsuba.reference`)
shares the roughness clamp and keeps its own float64 floors.

================  ======  ===========================================================================
name              value   where
================  ======  ===========================================================================
ROUGHNESS_MIN     0.03    r is clamped to [ROUGHNESS_MIN, 1] inside the BRDF only (α = r²)
GGX_D_FLOOR       1.2e-38 floor of the GGX denominator (‖n×h‖² + α²(n·h)²)²: just above float32's
                          smallest normal (1.18e-38), so that flushing denormals (the trainer's
                          ``torch.set_flush_denormal(True)``) cannot turn it into a 0 divisor
SMITH_FLOOR       1e-30   floor of the folded Smith denominators (c + √(α² + (1−α²)c²))
NORMAL_Z_MIN      1e-4    a normal-map value's n_z is clamped from below before normalising
================  ======  ===========================================================================

Python floats, converted by each backend (float32 in Dr.Jit and torch).
"""

from __future__ import annotations

ROUGHNESS_MIN = 0.03
GGX_D_FLOOR = 1.2e-38
SMITH_FLOOR = 1e-30
NORMAL_Z_MIN = 1e-4

__all__ = ["GGX_D_FLOOR", "NORMAL_Z_MIN", "ROUGHNESS_MIN", "SMITH_FLOOR"]
