"""Fast differentiable rendering of the planar sample (Dr.Jit, one shading point per pixel).

* :mod:`.inputs` — :class:`DrMaps`, :class:`DrLobes`, :class:`RenderOptions`;
* :mod:`.points` — the sample grid's shading points (``docs/conventions.md``, "Geometry and pixel grid");
* :mod:`.env_sg` — closed-form SG environment term;
* :mod:`.env_quadrature` — fixed-pattern MIS quadrature of the environment term;
* :mod:`.fast` — :func:`render`, :func:`render_numpy`, :func:`render_shots`, :func:`view_shot`.

The exemplar renders built on them live in :mod:`ebr_mitsuba.exemplar.images`.

Importing this package needs a Mitsuba variant only when a function is called.
"""

from .fast import render, render_numpy, render_shots, view_shot
from .inputs import DrLobes, DrMaps, RenderOptions

__all__ = [
    "DrLobes",
    "DrMaps",
    "RenderOptions",
    "render",
    "render_numpy",
    "render_shots",
    "view_shot",
]
