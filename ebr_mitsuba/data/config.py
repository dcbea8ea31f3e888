"""The typed TOML schema of ``ebr generate`` (defaults in one place, unknown keys rejected).

A config file has six tables; every key is optional unless marked *required*, and its default is
the one in the dataclass below (the single place defaults live). Precedence: these defaults <
the file < the command line (``--count``). An unknown key, a value of the wrong type or out of
range, or a missing file raises :class:`~ebr_mitsuba.errors.ConfigError` with one line naming the
file and the key (``materials[1].paths[0]``).

``[dataset]`` (:class:`DatasetSection`)

==============  =======  ==========  =========================================================
key             type     default     meaning
==============  =======  ==========  =========================================================
``seed``        int      0           data-set seed; sample i uses SeedSequence([seed, i, …])
``count``       int      100         number of samples (≥ 1; ``--count`` overrides)
``resolution``  int      256         H = W of every image and map, in [8, 4096]
==============  =======  ==========  =========================================================

``[capture]`` (:class:`CaptureSection`)

===================  =====  ========  ==============================================================
``setup``            str    "near"    ``near`` | ``near-far`` | ``five-light`` | ``multi-view``
                                      (one setup per data set, so every sample has the same tensors)
``flash_intensity``  float  10.0      point-light intensity, W/sr (> 0)
===================  =====  ========  ==============================================================

``[render]`` (:class:`RenderSection`)

===============  =====  ==========  ================================================================
``renderer``     str    "mitsuba"   ``mitsuba`` (path-traced, ``direct`` integrator) or ``fast``
                                    (:mod:`ebr_mitsuba.render`, one shading point per pixel)
``spp``          int    32          Mitsuba samples per pixel
``integrator``   str    "direct"    Mitsuba integrator: ``direct`` | ``path``
``fast_mode``    str    "sg"        fast renderer's environment term: ``sg`` | ``quadrature``
``fast_spp``     int    64          fast renderer's quadrature directions per pixel
===============  =====  ==========  ================================================================

``[exemplars]`` (:class:`ExemplarSection`): the uniform material (diffuse 0.1, specular 0.2,
flat normal) at each roughness, seen from the near camera and rendered with the data set's renderer.

===================  ===========  ======================  ===========================================
``env_roughness``    list[float]  [0.1, 0.3, 0.6, 0.9]    environment exemplars (flash off); [] = none
``point_roughness``  list[float]  [0.1, 0.3, 0.6, 0.9]    point-light exemplars (flash only); [] = none
===================  ===========  ======================  ===========================================

``[camera]`` (:class:`CameraSection`): the LDR photo simulation applied to the shots, in this
order: × exposure × white-balance gains → + noise → clip to [0, 1] → 8-bit sRGB.

=================  ===========  ==============  ==========================================================
``exposure``       float        1.0             base exposure (× radiance), > 0
``exposure_ev``    [lo, hi]     [-0.5, 0.5]     per-sample exposure jitter in stops, uniform
``white_balance``  float        0.05            R and B gains uniform in [1 − wb, 1 + wb] (G = 1), [0, 0.5)
``read_noise``     [lo, hi]     [0.0, 0.005]    std of additive Gaussian noise, uniform per sample
``shot_noise``     [lo, hi]     [0.0, 0.005]    signal-dependent variance per unit signal, uniform
``clip``           bool         true            clip photos to [0, 1] (saturation)
``quantize``       bool         true            8-bit sRGB PNG photos (needs ``clip``); else float EXR
``meter``          float        0.0             auto exposure, as a camera meters: > 0 sets the base
                                                exposure so that the 99th percentile of the
                                                largest channel of the brightest shot lands at this
                                                level (then × the ``exposure_ev`` jitter;
                                                ``exposure`` is ignored);
                                                0: the fixed ``exposure``. The exposure used is recorded
                                                in ``sample.json`` (as EXIF would)
=================  ===========  ==============  ==========================================================

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
import math
import os
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path

import tomllib

from ..errors import ConfigError, InputError
from ..geometry import DEFAULT_EXEMPLAR_ROUGHNESS, DEFAULT_FLASH_INTENSITY, SETUPS
from ..procedural import ENV_KINDS, INTENSITY_LEVELS
from ..scene import INTEGRATORS

RENDERERS = ("mitsuba", "fast")
SPLITS = ("train", "test", "all")  # = .split.SPLITS
FAST_MODES = ("sg", "quadrature")  # = ebr_mitsuba.render.inputs.MODES (not imported: no Dr.Jit here)
LEVELS = tuple(INTENSITY_LEVELS)
MIN_RES, MAX_RES = 8, 4096


def _meta(doc: str, **checks) -> dict:
    return {"doc": doc, **checks}


def _f(default, doc: str, **checks):
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda d=default: type(d)(d), metadata=_meta(doc, **checks))
    return field(default=default, metadata=_meta(doc, **checks))


# -- sections ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class DatasetSection:
    seed: int = _f(0, "data-set seed", minimum=0)
    count: int = _f(100, "number of samples", minimum=1)
    resolution: int = _f(256, "image and map size (square)", minimum=MIN_RES, maximum=MAX_RES)


@dataclass(frozen=True)
class CaptureSection:
    setup: str = _f("near", "capture setup", choices=SETUPS)
    flash_intensity: float = _f(DEFAULT_FLASH_INTENSITY, "flash intensity W/sr", positive=True)


@dataclass(frozen=True)
class RenderSection:
    renderer: str = _f("mitsuba", "renderer", choices=RENDERERS)
    spp: int = _f(32, "Mitsuba samples per pixel", minimum=1)
    integrator: str = _f("direct", "Mitsuba integrator", choices=INTEGRATORS)
    fast_mode: str = _f("sg", "fast renderer environment term", choices=FAST_MODES)
    fast_spp: int = _f(64, "fast renderer quadrature directions", minimum=1)


@dataclass(frozen=True)
class ExemplarSection:
    env_roughness: list[float] = _f(
        list(DEFAULT_EXEMPLAR_ROUGHNESS), "environment exemplar roughness", unit=True
    )
    point_roughness: list[float] = _f(
        list(DEFAULT_EXEMPLAR_ROUGHNESS), "point-light exemplar roughness", unit=True
    )


@dataclass(frozen=True)
class CameraSection:
    exposure: float = _f(1.0, "base exposure", positive=True)
    exposure_ev: tuple[float, float] = _f((-0.5, 0.5), "exposure jitter (stops)")
    white_balance: float = _f(0.05, "white-balance gain jitter", minimum=0.0, below=0.5)
    read_noise: tuple[float, float] = _f((0.0, 0.005), "read-noise std range", nonnegative=True)
    shot_noise: tuple[float, float] = _f((0.0, 0.005), "shot-noise gain range", nonnegative=True)
    clip: bool = _f(True, "clip photos to [0, 1]")
    quantize: bool = _f(True, "8-bit sRGB photos")
    meter: float = _f(
        0.0,
        "auto exposure: the brightest shot's 99th-percentile channel value (0: off)",
        minimum=0.0,
        maximum=1.0,
    )


@dataclass(frozen=True)
class ProceduralMaterials:
    type: str = _f("procedural", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)
    families: list[str] = _f([], "procedural families (empty: all)", family=True)
    augment: bool = _f(True, "random augmentation")
    blend: float = _f(0.3, "probability of blending two materials", minimum=0.0, maximum=1.0)


@dataclass(frozen=True)
class DirectoryMaterials:
    type: str = _f("directory", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)
    paths: list[str] = _f(
        [], "material directories or texture sets (glob patterns allowed)", path="dir", required=True
    )
    augment: bool = _f(True, "random augmentation")
    blend: float = _f(0.0, "probability of blending two materials", minimum=0.0, maximum=1.0)
    split: str = _f("all", "keep the train or test assets of the fixed test split, or all", choices=SPLITS)


@dataclass(frozen=True)
class ProceduralEnvironments:
    type: str = _f("procedural", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)
    kinds: list[str] = _f(list(ENV_KINDS), "procedural kinds", choices=ENV_KINDS, nonempty=True)
    levels: list[str] = _f(list(LEVELS), "intensity levels", choices=LEVELS, nonempty=True)


@dataclass(frozen=True)
class EquirectEnvironments:
    type: str = _f("equirect", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)
    paths: list[str] = _f(
        [], "equirectangular .hdr/.exr maps (glob patterns allowed)", path="file", required=True
    )
    split: str = _f("all", "keep the train or test assets of the fixed test split, or all", choices=SPLITS)
    levels: list[str] = _f(list(LEVELS), "intensity levels ([]: as in the file)", choices=LEVELS)
    rotate: bool = _f(True, "random rotation about z")
    lobes: int = _f(32, "SG ground-truth lobes", minimum=1, maximum=512)
    fit_iterations: int = _f(400, "SG fit Adam iterations", minimum=0)


@dataclass(frozen=True)
class SGEnvironments:
    type: str = _f("sg", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)
    paths: list[str] = _f([], "env.json files", path="file", required=True)
    levels: list[str] = _f([], "intensity levels ([]: as in the file)", choices=LEVELS)
    rotate: bool = _f(True, "random rotation about z")


@dataclass(frozen=True)
class NoEnvironment:
    type: str = _f("none", "source type")
    weight: float = _f(1.0, "relative probability", positive=True)


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
        _check_int(count, "--count", self.source, minimum=1)
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


def _type_name(value) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a number"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _err(source: str, key: str, msg: str) -> ConfigError:
    return ConfigError(f"{source}: '{key}' {msg}")


def _check_int(value, key: str, source: str, minimum=None, maximum=None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _err(source, key, f"must be an integer (got {_type_name(value)})")
    if minimum is not None and value < minimum:
        raise _err(source, key, f"must be >= {minimum} (got {value})")
    if maximum is not None and value > maximum:
        raise _err(source, key, f"must be <= {maximum} (got {value})")
    return int(value)


def _check_number(value, key: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _err(source, key, f"must be a number (got {_type_name(value)})")
    value = float(value)
    if not math.isfinite(value):
        raise _err(source, key, f"must be finite (got {value})")
    return value


_VAR = re.compile(r"\$(\w+)|\$\{(\w+)\}")


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
    for match in _VAR.finditer(text):
        name = match.group(1) or match.group(2)
        if name not in os.environ:
            raise _err(
                source,
                key,
                f"uses ${name}, which is not set; export {name} "
                f"(e.g. EBR_DATA_DIR=/path/to/shared/data) or write the path out",
            )
    path = Path(os.path.expanduser(os.path.expandvars(text)))
    if not path.is_absolute():
        path = base / path
    path = Path(os.path.normpath(path))
    if kind == "dir" and not path.is_dir():
        raise _err(source, key, f"names {path}, which is not an existing directory; fix the path")
    if kind == "file" and not path.is_file():
        raise _err(source, key, f"names {path}, which is not an existing file; fix the path")
    return str(path)


def _convert(value, hint, meta: dict, key: str, source: str, base: Path):
    origin = typing.get_origin(hint)
    if hint is bool:
        if not isinstance(value, bool):
            raise _err(source, key, f"must be true or false (got {_type_name(value)})")
        return value
    if hint is int:
        return _check_int(value, key, source, meta.get("minimum"), meta.get("maximum"))
    if hint is float:
        value = _check_number(value, key, source)
        if meta.get("positive") and value <= 0:
            raise _err(source, key, f"must be > 0 (got {value})")
        if "minimum" in meta and value < meta["minimum"]:
            raise _err(source, key, f"must be >= {meta['minimum']} (got {value})")
        if "maximum" in meta and value > meta["maximum"]:
            raise _err(source, key, f"must be <= {meta['maximum']} (got {value})")
        if "below" in meta and value >= meta["below"]:
            raise _err(source, key, f"must be < {meta['below']} (got {value})")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise _err(source, key, f"must be a string (got {_type_name(value)})")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise _err(source, key, f"is {value!r}; use one of {', '.join(choices)}")
        return value
    if origin is tuple:  # a [lo, hi] range
        if not isinstance(value, list) or len(value) != 2:
            raise _err(source, key, f"must be a list [low, high] of two numbers (got {_type_name(value)})")
        lo, hi = (_check_number(v, f"{key}[{i}]", source) for i, v in enumerate(value))
        if lo > hi:
            raise _err(source, key, f"is [{lo}, {hi}]; low must be <= high")
        if meta.get("nonnegative") and lo < 0:
            raise _err(source, key, f"must be >= 0 (got [{lo}, {hi}])")
        return (lo, hi)
    if origin is list:
        (inner,) = typing.get_args(hint)
        if not isinstance(value, list):
            raise _err(source, key, f"must be a list (got {_type_name(value)})")
        if meta.get("nonempty") and not value:
            raise _err(source, key, "must not be empty")
        out = []
        for i, item in enumerate(value):
            k = f"{key}[{i}]"
            if inner is float:
                v = _check_number(item, k, source)
                if meta.get("unit") and not 0.0 <= v <= 1.0:
                    raise _err(source, k, f"must be in [0, 1] (got {v})")
                out.append(v)
            else:
                if not isinstance(item, str):
                    raise _err(source, k, f"must be a string (got {_type_name(item)})")
                if meta.get("choices") and item not in meta["choices"]:
                    raise _err(source, k, f"is {item!r}; use one of {', '.join(meta['choices'])}")
                if meta.get("family"):
                    from ..procedural import FAMILIES

                    if item not in FAMILIES:
                        raise _err(
                            source,
                            k,
                            f"is {item!r}, not a procedural family; use one of {', '.join(FAMILIES)}",
                        )
                if meta.get("path"):
                    out.extend(_resolve_paths(item, k, source, base, meta["path"]))
                    continue
                out.append(item)
        return out
    raise TypeError(f"config schema: unsupported field type {hint!r} for {key}")  # pragma: no cover


def _parse_table(cls, table, key: str, source: str, base: Path):
    if not isinstance(table, dict):
        raise _err(source, key, f"must be a table (got {_type_name(table)})")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(table) - set(fields))
    if unknown:
        where = f"{key}.{unknown[0]}"
        raise _err(source, where, f"is not a known key; {key} takes {', '.join(fields)}")
    values = {}
    for name, f in fields.items():
        if name in table:
            values[name] = _convert(table[name], hints[name], dict(f.metadata), f"{key}.{name}", source, base)
        elif f.metadata.get("required"):
            raise _err(source, f"{key}.{name}", "is required")
    if "paths" in fields and not values.get("paths"):
        raise _err(source, f"{key}.paths", "must list at least one path")
    if "split" in fields and "paths" in values:
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
            raise _err(source, f"{k}.type", f"is {kind!r}; use one of {', '.join(types)}")
        out.append(_parse_table(types[kind], item, k, source, base))
    if not out:
        raise _err(source, key, f"needs at least one [[{key}]] table")
    return tuple(out)


def parse_config(doc: dict, source: str = "<memory>", base_dir: str | Path = ".") -> GenerateConfig:
    """Validate a parsed TOML document (see the module docstring)."""
    base = Path(base_dir)
    unknown = sorted(set(doc) - set(SECTIONS) - set(ARRAYS))
    if unknown:
        raise _err(source, unknown[0], f"is not a known table; use {', '.join([*SECTIONS, *ARRAYS])}")
    values = {
        name: _parse_table(cls, doc.get(name, {}), name, source, base) for name, cls in SECTIONS.items()
    }
    for name in ARRAYS:
        if name not in doc:
            hint = ' (type = "none" for a dark environment)' if name == "environments" else ""
            raise _err(source, name, f"is missing; add at least one [[{name}]] table{hint}")
        values[name] = _parse_sources(doc[name], name, ARRAYS[name], source, base)
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
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file; give a TOML config") from None
    return parse_config(doc, source=str(path), base_dir=path.resolve().parent)


def schema_table() -> list[tuple[str, str, str, str]]:
    """(key, type, default, meaning) of every table key, for the docs."""
    rows = []
    groups = (
        list(SECTIONS.items())
        + [(f"materials ({t})", c) for t, c in MATERIAL_TYPES.items()]
        + [(f"environments ({t})", c) for t, c in ENVIRONMENT_TYPES.items()]
    )
    for name, cls in groups:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                default = f.default
            else:
                default = f.default_factory()
            rows.append(
                (
                    f"{name}.{f.name}",
                    getattr(hints[f.name], "__name__", str(hints[f.name])),
                    json.dumps(_jsonable(default)),
                    f.metadata.get("doc", ""),
                )
            )
    return rows
