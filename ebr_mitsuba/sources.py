"""Material and environment *specs* of the command line, parsed into what a capture renders.

=====================  =================================================================================
spec                   meaning
=====================  =================================================================================
material ``DIR``       a material directory (``normal``/``diffuse``/``specular``/``roughness`` maps and
                       ``material.json``) or a Poly Haven / ambientCG texture set, read by
                       :func:`ebr_mitsuba.materials.load_material`
``procedural:F:S``     :func:`ebr_mitsuba.procedural.make_material` of family ``F`` with integer seed ``S``
env ``FILE.json``      an SG environment file (``env.json``, format ``ebr-sg/1``)
env ``FILE.exr|.hdr``  an equirectangular map (Mitsuba's y-up layout; rotated to z-up on load)
``procedural:S``       :func:`ebr_mitsuba.procedural.make_environment` with integer seed ``S``
=====================  =================================================================================

:func:`parse_material` and :func:`parse_env` check the spec (files exist, family known, JSON
valid) and raise a one-line :class:`~ebr_mitsuba.errors.InputError` naming the spec otherwise, so
a command fails before it writes anything.

A material is rendered at the capture resolution: :meth:`MaterialSource.load` resamples the maps
of a directory by exact area averaging (normals renormalised); the maps must be square. A
procedural material is generated at that resolution.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError
from .sgenv import SGEnvironment
from .svbrdf import SVBRDF

PROCEDURAL = "procedural"
EQUIRECT_SUFFIXES = (".exr", ".hdr")


def _int_seed(text: str, spec: str, what: str) -> int:
    try:
        seed = int(text)
    except ValueError:
        raise InputError(
            f"{what} {spec!r}: seed {text!r} is not an integer; write "
            f"{'procedural:FAMILY:SEED' if what == 'material' else 'procedural:SEED'}"
        ) from None
    if seed < 0:
        raise InputError(f"{what} {spec!r}: seed must be >= 0 (got {seed})")
    return seed


# -- materials --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MaterialSource:
    """A parsed material spec: ``kind`` is ``"directory"`` (``path``) or ``"procedural"``
    (``family``, ``seed``)."""

    spec: str
    kind: str
    path: Path | None = None
    family: str | None = None
    seed: int | None = None

    def load(self, size: int) -> SVBRDF:
        """The material's maps at ``size``×``size`` (row 0 = +y)."""
        if self.kind == PROCEDURAL:
            from .procedural import make_material

            return make_material(self.family, self.seed, size)
        from .materials import load_material

        return fit_to_resolution(load_material(self.path), size, source=str(self.path))

    def to_json(self) -> dict:
        out = {"spec": self.spec, "kind": self.kind}
        if self.kind == PROCEDURAL:
            out.update(family=self.family, seed=self.seed)
        else:
            out["path"] = str(self.path.resolve())
        return out


def parse_material(spec: str) -> MaterialSource:
    """Parse ``DIR`` or ``procedural:FAMILY:SEED`` (see module docstring)."""
    spec = str(spec)
    if spec.startswith(PROCEDURAL + ":"):
        parts = spec.split(":")
        if len(parts) != 3 or not parts[1]:
            raise InputError(f"material {spec!r}: write procedural:FAMILY:SEED (e.g. procedural:wood:3)")
        from .procedural import FAMILIES

        family = parts[1]
        if family not in FAMILIES:
            raise InputError(
                f"material {spec!r}: unknown procedural family {family!r}; use one of {', '.join(FAMILIES)}"
            )
        return MaterialSource(spec, PROCEDURAL, family=family, seed=_int_seed(parts[2], spec, "material"))
    path = Path(spec)
    if not path.exists():
        raise InputError(
            f"{path}: no such material directory; give a directory with normal, diffuse, "
            f"specular and roughness maps, or procedural:FAMILY:SEED"
        )
    if not path.is_dir():
        raise InputError(f"{path}: is not a directory; give a material directory or procedural:FAMILY:SEED")
    return MaterialSource(spec, "directory", path=path)


def center_square(svbrdf: SVBRDF) -> SVBRDF:
    """The largest centred square crop of ``svbrdf`` (itself when already square)."""
    h, w = svbrdf.shape
    if h == w:
        return svbrdf
    k = min(h, w)
    i, j = (h - k) // 2, (w - k) // 2
    crop = [
        a[i : i + k, j : j + k] for a in (svbrdf.normal, svbrdf.diffuse, svbrdf.specular, svbrdf.roughness)
    ]
    return SVBRDF(*crop, source=f"{svbrdf.source}+crop{k}")


def fit_to_resolution(svbrdf: SVBRDF, size: int, source: str = "material") -> SVBRDF:
    """``svbrdf`` area-resampled to ``size``×``size``
    (:func:`ebr_mitsuba.materials.resample_svbrdf`); non-square maps are an InputError."""
    h, w = svbrdf.shape
    if h != w:
        raise InputError(f"{source}: maps are {w}x{h}; a capture needs square maps (crop them)")
    from .materials import resample_svbrdf

    return resample_svbrdf(svbrdf, size)


# -- environments -----------------------------------------------------------------------------------


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class EnvSource:
    """A parsed environment spec. ``kind`` is ``"sg"`` (``sg`` holds the lobes; from an
    ``env.json`` ``path`` or ``procedural`` ``seed``) or ``"equirect"`` (``path``, ``sha256`` and
    the loaded ``equirect`` map)."""

    spec: str
    kind: str
    path: Path | None = None
    sg: SGEnvironment | None = None
    seed: int | None = None
    sha256: str | None = None
    equirect: object | None = None  # ebr_mitsuba.envmap.EquirectMap (imported lazily)

    def emitter_dict(self, scale: float = 1.0) -> dict:
        """The Mitsuba emitter of this environment (``sgenvmap`` or rotated ``envmap``)."""
        from .scene import equirect_emitter_dict, sg_emitter_dict

        if self.kind == "sg":
            return sg_emitter_dict(self.sg, scale)
        return equirect_emitter_dict(self.equirect if self.equirect is not None else self.path, scale)

    def to_json(self) -> dict:
        out = {"spec": self.spec, "kind": self.kind}
        if self.path is not None:
            out["path"] = str(self.path.resolve())
        if self.seed is not None:
            out["seed"] = self.seed
        if self.sha256 is not None:
            out["sha256"] = self.sha256
        if self.sg is not None:
            out["lobes"] = self.sg.num_lobes
        if self.equirect is not None:
            out["shape"] = list(self.equirect.data.shape)
        return out


def parse_env(spec: str) -> EnvSource:
    """Parse ``env.json``, ``FILE.exr``/``FILE.hdr`` or ``procedural:SEED`` (see module docstring)."""
    spec = str(spec)
    if spec.startswith(PROCEDURAL + ":"):
        parts = spec.split(":")
        if len(parts) != 2:
            raise InputError(f"environment {spec!r}: write procedural:SEED (e.g. procedural:7)")
        seed = _int_seed(parts[1], spec, "environment")
        from .procedural import make_environment

        return EnvSource(spec, "sg", sg=make_environment(seed), seed=seed)
    path = Path(spec)
    suffix = path.suffix.lower()
    if suffix == ".json":
        return EnvSource(spec, "sg", path=path, sg=SGEnvironment.load(path))
    if suffix in EQUIRECT_SUFFIXES:
        if not path.is_file():
            raise InputError(
                f"{path}: no such environment map; give an existing equirectangular .exr/.hdr file"
            )
        from .envmap import load_equirect

        emap = load_equirect(path)  # validates the file now, before anything is written
        return EnvSource(spec, "equirect", path=path, sha256=file_sha256(path), equirect=emap)
    raise InputError(
        f"{path}: unknown environment type {suffix or '(no suffix)'!r}; give an env.json, "
        f"an equirectangular .exr/.hdr or procedural:SEED"
    )
