"""Exemplars: the exemplar material (here), its images, the adaptive selection and the files.

An exemplar is a render of one uniform material under the capture's light, in the photos' pixel
grid (``docs/conventions.md``, "Exemplars"); the lighting net predicts environment exemplars, the
cascade reads the selected ones.

==============  ===================================================================================
module          contents
==============  ===================================================================================
(this package)  the exemplar material's constants (table below); imports nothing of the package
``images``      exemplar renders: environment (fast renderer), point-light, ``ebr exemplars``'
                Mitsuba or fast renders, the selection's basis renders
``select``      adaptive exemplar selection (:class:`~.select.SelectConfig`,
                :func:`~.select.select_exemplars`)
``files``       exemplar directories: :func:`~.files.write_exemplars`, :func:`~.files.read_exemplars`
==============  ===================================================================================

The exemplar material, the uniform material every exemplar is a render of:

==================  ===========  ===============================================================
name                value        meaning
==================  ===========  ===============================================================
EXEMPLAR_DIFFUSE    0.1          diffuse albedo, the same on R, G and B
EXEMPLAR_SPECULAR   0.2          specular F₀, the same on R, G and B
roughness           per exemplar (``DEFAULT_EXEMPLAR_ROUGHNESS`` in :mod:`ebr_mitsuba.geometry`)
normal              (0, 0, 1)    flat
==================  ===========  ===============================================================

``docs/conventions.md`` ("Exemplars") defines exemplars; ``scenes/exemplar.xml`` writes the same
two values (a test checks it). ``SVBRDF.uniform(h, w, roughness=r)`` is the exemplar material by
default. This package's ``__init__`` imports nothing of the package, so that every other module may
import the constants; its modules import what they render with.
"""

from __future__ import annotations

EXEMPLAR_DIFFUSE = 0.1
EXEMPLAR_SPECULAR = 0.2


def exemplar_material_json() -> dict:
    """The material as recorded in an exemplar directory's or data set's metadata."""
    return {"diffuse": EXEMPLAR_DIFFUSE, "specular": EXEMPLAR_SPECULAR, "normal": [0.0, 0.0, 1.0]}


__all__ = ["EXEMPLAR_DIFFUSE", "EXEMPLAR_SPECULAR", "exemplar_material_json"]
