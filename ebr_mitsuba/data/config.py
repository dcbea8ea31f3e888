"""The typed TOML schema of ``ebr generate`` (defaults in one place, unknown keys rejected).

A config file has six tables; every key is optional unless marked *required*, and its default is
the one in the dataclass below (the single place defaults live). Precedence: these defaults <
the file < the command line (``--count``). An unknown key, a value of the wrong type or out of
range, or a missing file raises :class:`~ebr_mitsuba.errors.ConfigError` with one line naming the
file and the key (``materials[1].paths[0]``).

``[dataset]`` (:class:`DatasetSection`)

.. options:: DatasetSection

``[capture]`` (:class:`CaptureSection`)

.. options:: CaptureSection

``[render]`` (:class:`RenderSection`)

.. options:: RenderSection

``[exemplars]`` (:class:`ExemplarSection`): the uniform material (diffuse 0.1, specular 0.2,
flat normal) at each roughness, seen from the near camera and rendered with the data set's renderer.

.. options:: ExemplarSection

``[camera]`` (:class:`CameraSection`): the LDR photo simulation applied to the shots, in this
order: × exposure × white-balance gains → + noise → clip to [0, 1] → 8-bit sRGB.

.. options:: CameraSection

``[[materials]]`` (at least one; *required* ``type``): sources drawn with probability ∝ ``weight``.

* ``type = "procedural"`` (:class:`ProceduralMaterials`): ``families`` (list of
  :data:`ebr_mitsuba.procedural.FAMILIES`, default all), ``augment`` (bool, true), ``blend``
  (probability of blending with a second material of the source, 0.3), ``weight`` (1.0).
* ``type = "directory"`` (:class:`DirectoryMaterials`): ``paths`` (*required*, material directories or
  Poly Haven / ambientCG texture sets, sets listed in a ``materials_extra/index.json`` included),
  ``augment``, ``blend``, ``weight``, ``split`` (below).

``[[environments]]`` (at least one; *required* ``type``):

* ``type = "procedural"`` (:class:`ProceduralEnvironments`): ``kinds`` (of
  :data:`ebr_mitsuba.procedural.ENV_KINDS`, default all), ``levels`` (of ``low``/``medium``/
  ``high``, default all), ``weight``.
* ``type = "equirect"`` (:class:`EquirectEnvironments`): ``paths`` (*required*, ``.hdr``/``.exr``),
  ``levels`` (scale each map so its irradiance on the sample is that level × the flash's; [] keeps
  the file's radiance), ``rotate`` (random rotation about z, true), ``lobes`` (SG ground-truth fit,
  32), ``fit_iterations`` (400), ``weight``, ``split`` (below).
* ``type = "sg"`` (:class:`SGEnvironments`): ``paths`` (*required*, ``env.json``), ``levels`` ([]),
  ``rotate`` (true), ``weight``.
* ``type = "none"`` (:class:`NoEnvironment`): dark (the five-light setup needs no environment),
  ``weight``.

Paths: ``~`` and ``$VAR``/``${VAR}`` are expanded (an unset variable is an error naming it), then
relative paths are taken from the config file's directory. Files must exist when the config loads.
A path with ``*``, ``?`` or ``[`` is a glob pattern standing for its sorted matches (directories
for ``directory`` materials, files for ``equirect`` maps).

``split`` (``directory`` materials and ``equirect`` maps; ``"all"`` by default) filters the paths by
the fixed test split of the real assets (``scenes/test_split.toml``, :mod:`.split`): ``"train"``
drops the test assets a pattern matched and refuses a test asset named outright; ``"test"`` keeps
only test assets. Training configs use ``"train"``, evaluation configs ``"test"``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError, InputError
from ..geometry import DEFAULT_EXEMPLAR_ROUGHNESS, DEFAULT_FLASH_INTENSITY, SETUPS
from ..procedural import ENV_KINDS, FAMILIES, INTENSITY_LEVELS
from ..scene import INTEGRATORS
from ..typedconfig import (
    Meta,
    config,
    convert,
    convert_table,
    document,
    expand_path,
    meta_of,
    option,
    read_toml,
    rows,
    unknown_keys,
)

RENDERERS = ("mitsuba", "fast")
SPLITS = ("train", "test", "all")  # = .split.SPLITS
FAST_MODES = ("sg", "quadrature")  # = ebr_mitsuba.render.inputs.MODES (not imported: no Dr.Jit here)
LEVELS = tuple(INTENSITY_LEVELS)
MIN_RES, MAX_RES = 8, 4096


# -- sections ----------------------------------------------------------------------------------

_PROB = {"minimum": 0.0, "maximum": 1.0}


def _weight():
    return option(1.0, "relative probability of this source", above=0)


def _paths(meaning: str, kind: str):
    """A required list of glob patterns naming asset files (``kind = "file"``) or folders (``"dir"``)."""
    return option([], meaning, required=True, extra={"path": kind})


def _split():
    return option(
        "all",
        "keep the train or test assets of the fixed test split, or all (see below)",
        choices=SPLITS,
    )


@config
class DatasetSection:
    """The ``[dataset]`` table."""

    seed: int = option(0, "data-set seed; sample i uses SeedSequence([seed, i, …])", minimum=0)
    count: int = option(100, "number of samples (--count overrides)", minimum=1)
    resolution: int = option(256, "H = W of every image and map", minimum=MIN_RES, maximum=MAX_RES)


@config
class CaptureSection:
    """The ``[capture]`` table."""

    setup: str = option(
        "near", "capture setup (one per data set, so every sample has the same tensors)", choices=SETUPS
    )
    flash_intensity: float = option(DEFAULT_FLASH_INTENSITY, "point-light intensity, W/sr", above=0)
    noflash_view: bool = option(
        False,
        "multi-view only: also the centre camera without its flash (the noflash view of ebr capture "
        "--setup multi-view), for ebr estimate --views' lighting scale and ebr insert's compositing; "
        "the networks read the nine flash views",
    )


@config
class RenderSection:
    """The ``[render]`` table."""

    renderer: str = option(
        "mitsuba",
        "mitsuba (path-traced, direct integrator) or fast (ebr_mitsuba.render, one shading point per pixel)",
        choices=RENDERERS,
    )
    spp: int = option(32, "Mitsuba samples per pixel", minimum=1)
    integrator: str = option("direct", "Mitsuba integrator", choices=INTEGRATORS)
    fast_mode: str = option("sg", "fast renderer's environment term", choices=FAST_MODES)
    fast_spp: int = option(64, "fast renderer's quadrature directions per pixel", minimum=1)


@config
class ExemplarSection:
    """The ``[exemplars]`` table."""

    env_roughness: list[float] = option(
        list(DEFAULT_EXEMPLAR_ROUGHNESS), "environment exemplars (flash off); [] = none", **_PROB
    )
    point_roughness: list[float] = option(
        list(DEFAULT_EXEMPLAR_ROUGHNESS), "point-light exemplars (flash only); [] = none", **_PROB
    )


@config
class CameraSection:
    """The ``[camera]`` table."""

    exposure: float = option(1.0, "base exposure (× radiance)", above=0)
    exposure_ev: tuple[float, float] = option(
        (-0.5, 0.5), "per-sample exposure jitter in stops, uniform in [lo, hi]", ordered=True
    )
    white_balance: float = option(
        0.05, "R and B gains uniform in [1 − wb, 1 + wb] (G = 1)", minimum=0.0, below=0.5
    )
    read_noise: tuple[float, float] = option(
        (0.0, 0.005),
        "std of additive Gaussian noise, uniform per sample in [lo, hi]",
        minimum=0,
        ordered=True,
    )
    shot_noise: tuple[float, float] = option(
        (0.0, 0.005),
        "signal-dependent variance per unit signal, uniform in [lo, hi]",
        minimum=0,
        ordered=True,
    )
    clip: bool = option(True, "clip photos to [0, 1] (saturation)")
    quantize: bool = option(True, "8-bit sRGB PNG photos (needs clip); else float EXR")
    meter: float = option(
        0.0,
        "auto exposure, as a camera meters: > 0 sets the base exposure so that the 99th percentile "
        "of the largest channel of the brightest shot lands at this level (then × the exposure_ev "
        "jitter; exposure is ignored); 0: the fixed exposure. The exposure used is recorded in "
        "sample.json (as EXIF would)",
        **_PROB,
    )


@config
class ProceduralMaterials:
    """``[[materials]]`` with ``type = "procedural"``."""

    type: str = option("procedural", "source type")
    weight: float = _weight()
    families: list[str] = option([], "procedural families (empty: all)", choices=FAMILIES)
    augment: bool = option(True, "random augmentation")
    blend: float = option(0.3, "probability of blending with a second material of the source", **_PROB)


@config
class DirectoryMaterials:
    """``[[materials]]`` with ``type = "directory"``."""

    type: str = option("directory", "source type")
    weight: float = _weight()
    paths: list[str] = _paths(
        "material directories or Poly Haven / ambientCG texture sets (glob patterns allowed)", "dir"
    )
    augment: bool = option(True, "random augmentation")
    blend: float = option(0.0, "probability of blending with a second material of the source", **_PROB)
    split: str = _split()


@config
class ProceduralEnvironments:
    """``[[environments]]`` with ``type = "procedural"``."""

    type: str = option("procedural", "source type")
    weight: float = _weight()
    kinds: list[str] = option(list(ENV_KINDS), "procedural kinds", choices=ENV_KINDS, nonempty=True)
    levels: list[str] = option(list(LEVELS), "intensity levels", choices=LEVELS, nonempty=True)


@config
class EquirectEnvironments:
    """``[[environments]]`` with ``type = "equirect"``."""

    type: str = option("equirect", "source type")
    weight: float = _weight()
    paths: list[str] = _paths("equirectangular .hdr/.exr maps (glob patterns allowed)", "file")
    split: str = _split()
    levels: list[str] = option(
        list(LEVELS),
        "scale each map so its irradiance on the sample is that level × the flash's ([]: as in the file)",
        choices=LEVELS,
    )
    rotate: bool = option(True, "random rotation about z")
    lobes: int = option(32, "SG ground-truth fit lobes", minimum=1, maximum=512)
    fit_iterations: int = option(400, "SG fit Adam iterations", minimum=0)


@config
class SGEnvironments:
    """``[[environments]]`` with ``type = "sg"``."""

    type: str = option("sg", "source type")
    weight: float = _weight()
    paths: list[str] = _paths("env.json files", "file")
    levels: list[str] = option([], "intensity levels ([]: as in the file)", choices=LEVELS)
    rotate: bool = option(True, "random rotation about z")


@config
class NoEnvironment:
    """``[[environments]]`` with ``type = "none"``: dark."""

    type: str = option("none", "source type")
    weight: float = _weight()


MATERIAL_TYPES = {"procedural": ProceduralMaterials, "directory": DirectoryMaterials}
ENVIRONMENT_TYPES = {
    "procedural": ProceduralEnvironments,
    "equirect": EquirectEnvironments,
    "sg": SGEnvironments,
    "none": NoEnvironment,
}
SECTIONS = {
    "dataset": DatasetSection,
    "capture": CaptureSection,
    "render": RenderSection,
    "exemplars": ExemplarSection,
    "camera": CameraSection,
}
ARRAYS = {"materials": MATERIAL_TYPES, "environments": ENVIRONMENT_TYPES}

MaterialSpec = ProceduralMaterials | DirectoryMaterials
EnvironmentSpec = ProceduralEnvironments | EquirectEnvironments | SGEnvironments | NoEnvironment


@dataclass(frozen=True)
class GenerateConfig:
    """A validated ``ebr generate`` config (see the module docstring)."""

    dataset: DatasetSection = field(default_factory=DatasetSection)
    capture: CaptureSection = field(default_factory=CaptureSection)
    render: RenderSection = field(default_factory=RenderSection)
    exemplars: ExemplarSection = field(default_factory=ExemplarSection)
    camera: CameraSection = field(default_factory=CameraSection)
    materials: tuple = ()
    environments: tuple = ()
    source: str = "<memory>"

    def with_count(self, count: int) -> GenerateConfig:
        """The config with ``dataset.count`` replaced (the ``--count`` override)."""
        count = convert(count, int, Meta("", minimum=1), where=self.source, key="--count")
        return dataclasses.replace(self, dataset=dataclasses.replace(self.dataset, count=int(count)))

    def with_changes(self, section: str, **changes) -> GenerateConfig:
        """The config with keys of one table replaced (validated like the file)."""
        current = dataclasses.asdict(getattr(self, section))
        current.update(changes)
        table = _parse_table(SECTIONS[section], current, section, self.source, Path("."))
        return dataclasses.replace(self, **{section: table})

    def to_json(self) -> dict:
        """The normalised config (absolute paths, every default filled in), JSON-ready."""
        out = {name: _jsonable(dataclasses.asdict(getattr(self, name))) for name in SECTIONS}
        if not self.capture.noflash_view:  # off: the fingerprint of the data sets made before it
            del out["capture"]["noflash_view"]
        out["materials"] = [_jsonable(dataclasses.asdict(m)) for m in self.materials]
        out["environments"] = [_jsonable(dataclasses.asdict(e)) for e in self.environments]
        return out

    def fingerprint(self) -> str:
        """SHA-256 of :meth:`to_json` without ``dataset.count``: samples of configs with the same
        fingerprint are identical, so ``--resume`` may extend a data set to a larger count."""
        doc = self.to_json()
        doc["dataset"].pop("count")
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


# -- parsing -----------------------------------------------------------------------------------


def _err(source: str, key: str, msg: str) -> ConfigError:
    return ConfigError(f"{source}: {key}: {msg}")


_GLOB_CHARS = re.compile(r"[*?\[]")


def _resolve_paths(text: str, key: str, source: str, base: Path, kind: str) -> list[str]:
    """One path, or every match (sorted) of a glob pattern (``materials_extra/*``)."""
    if not _GLOB_CHARS.search(text):
        return [_resolve_path(text, key, source, base, kind)]
    pattern = _resolve_path(text, key, source, base, None)
    import glob

    want = {"dir": os.path.isdir, "file": os.path.isfile}.get(kind, os.path.exists)
    found = sorted(p for p in glob.glob(pattern) if want(p))
    if not found:
        raise _err(
            source,
            key,
            f"pattern {pattern} matches no {'directory' if kind == 'dir' else 'file'}; fix the pattern",
        )
    return found


def _resolve_path(text: str, key: str, source: str, base: Path, kind: str | None) -> str:
    path = Path(os.path.normpath(expand_path(text, base, where=source, key=key)))
    if kind == "dir" and not path.is_dir():
        raise _err(source, key, f"names {path}, which is not an existing directory; fix the path")
    if kind == "file" and not path.is_file():
        raise _err(source, key, f"names {path}, which is not an existing file; fix the path")
    return str(path)


def _parse_table(cls, table, key: str, source: str, base: Path):
    """One table: the engine's checks (:func:`ebr_mitsuba.typedconfig.convert_table`), then the
    path fields resolved (and filtered by ``split``)."""
    values = convert_table(cls, table, source, key=key)
    for f in dataclasses.fields(cls):
        kind = meta_of(f).extra.get("path")
        if kind and f.name in values:
            values[f.name] = [
                p
                for i, text in enumerate(values[f.name])
                for p in _resolve_paths(text, f"{key}.{f.name}[{i}]", source, base, kind)
            ]
    if "paths" in values and not values["paths"]:
        raise _err(source, f"{key}.paths", "must list at least one path")
    if "paths" in values and "split" in {f.name for f in dataclasses.fields(cls)}:
        values["paths"] = _apply_split(table, values, key, source, base)
    return cls(**values)


def _apply_split(table: dict, values: dict, key: str, source: str, base: Path) -> list[str]:
    """Keep the paths of the split: ``train`` drops the fixed test assets (:mod:`.split`) that a
    pattern matched and refuses one named outright; ``test`` keeps only test assets."""
    from .split import load_split

    split = values.get("split", "all")
    if split == "all":
        return values["paths"]
    test = load_split()
    explicit = set()
    for i, text in enumerate(table.get("paths", [])):
        if isinstance(text, str) and not _GLOB_CHARS.search(text):
            explicit.add(_resolve_path(text, f"{key}.paths[{i}]", source, base, None))
    kept = []
    for path in values["paths"]:
        in_test = test.is_test(path)
        if split == "train" and in_test and path in explicit:
            raise _err(
                source,
                f"{key}.paths",
                f"names {path}, which is in the fixed test split "
                f'({test.source}); remove it, or set split = "all"',
            )
        if in_test == (split == "test"):
            kept.append(path)
    if not kept:
        raise _err(
            source, f"{key}.paths", f"keeps no path of the {split!r} split; check the paths and EBR_DATA_DIR"
        )
    return kept


def _parse_sources(items, key: str, types: dict, source: str, base: Path) -> tuple:
    if not isinstance(items, list) or not all(isinstance(t, dict) for t in items):
        raise _err(source, key, f"must be an array of tables ([[{key}]])")
    out = []
    for i, item in enumerate(items):
        k = f"{key}[{i}]"
        kind = item.get("type")
        if kind is None:
            raise _err(source, f"{k}.type", f"is required; use one of {', '.join(types)}")
        if kind not in types:
            raise _err(source, f"{k}.type", f"got {kind!r}; use one of {', '.join(types)}")
        out.append(_parse_table(types[kind], item, k, source, base))
    if not out:
        raise _err(source, key, f"needs at least one [[{key}]] table")
    return tuple(out)


def parse_config(doc: dict, source: str = "<memory>", base_dir: str | Path = ".") -> GenerateConfig:
    """Validate a parsed TOML document (see the module docstring)."""
    base = Path(base_dir)
    unknown_keys(doc, [*SECTIONS, *ARRAYS], where=source, noun="table")
    values = {
        name: _parse_table(cls, doc.get(name, {}), name, source, base) for name, cls in SECTIONS.items()
    }
    for name in ARRAYS:
        if name not in doc:
            hint = ' (type = "none" for a dark environment)' if name == "environments" else ""
            raise _err(source, name, f"is missing; add at least one [[{name}]] table{hint}")
        values[name] = _parse_sources(doc[name], name, ARRAYS[name], source, base)
    if values["capture"].noflash_view and values["capture"].setup != "multi-view":
        raise _err(
            source,
            "capture.noflash_view",
            f"applies to the multi-view setup only (the {values['capture'].setup} setup has its own "
            "shots); remove it",
        )
    cam = values["camera"]
    if cam.quantize and not cam.clip:
        raise _err(source, "camera.quantize", "needs camera.clip = true (8-bit codes hold [0, 1])")
    return GenerateConfig(**values, source=source)


def bundled_configs() -> list[str]:
    """Names (without ``.toml``) of the example configs shipped in :mod:`ebr_mitsuba.scenes`."""
    import importlib.resources

    root = importlib.resources.files("ebr_mitsuba.scenes")
    return sorted(
        p.name[:-5]
        for p in root.iterdir()
        if p.name.endswith(".toml") and p.name not in ("validation.toml", "test_split.toml")
    )


def resolve_config_path(spec: str | Path) -> Path:
    """``spec`` itself when it is a file, else the bundled example config of that bare name."""
    import importlib.resources

    path = Path(spec)
    if path.is_file():
        return path
    if path.parent == Path(".") and path.suffix in ("", ".toml"):
        bundled = importlib.resources.files("ebr_mitsuba.scenes") / f"{path.stem}.toml"
        if bundled.is_file():
            return Path(str(bundled))
    raise InputError(
        f"{path}: no such config file; give a TOML file or one of the bundled examples "
        f"({', '.join(bundled_configs())})"
    )


def load_config(path: str | Path) -> GenerateConfig:
    """Read and validate a TOML config file (or a bundled example given by its bare name)."""
    path = resolve_config_path(path)
    return parse_config(read_toml(path), source=str(path), base_dir=path.resolve().parent)


def schema_table() -> list[tuple[str, str, str, str]]:
    """(key, type, default, meaning) of every table key, for the docs (from the field metadata)."""
    groups = (
        list(SECTIONS.items())
        + [(f"materials ({t})", c) for t, c in MATERIAL_TYPES.items()]
        + [(f"environments ({t})", c) for t, c in ENVIRONMENT_TYPES.items()]
    )
    return [(k, t, d, m) for name, cls in groups for k, t, d, _, m in rows(cls, prefix=f"{name}.")]


__doc__ = document(
    __doc__,
    DatasetSection=DatasetSection,
    CaptureSection=CaptureSection,
    RenderSection=RenderSection,
    ExemplarSection=ExemplarSection,
    CameraSection=CameraSection,
)
