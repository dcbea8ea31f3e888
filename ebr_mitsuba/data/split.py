"""The fixed test split of the real assets (``docs/conventions.md``, "Metrics", evaluation
protocol), read from ``scenes/test_split.toml``.

The split names material sets and HDR maps by their path relative to the shared data folder
(``$EBR_DATA_DIR``). Everything else under ``materials/``, ``materials_extra/``, ``envmaps/`` and
``envmaps_extra/`` is training data. A training config that names a test asset is refused
(:func:`check_training_paths`), so no model can be selected on the test split by accident.

=========================  =============================================================
function                   what it gives
=========================  =============================================================
``load_split()``           the :class:`TestSplit` (bundled file, or a given path)
``data_dir()``             ``$EBR_DATA_DIR`` (or ``../shared/data`` beside the checkout)
``real_materials(split)``  absolute paths of the training / test / all real material sets
``real_envmaps(split)``    absolute paths of the training / test / all real HDR maps
``material_class(path)``   a real set's class (``index.json``), else ``"procedural"`` / name
=========================  =============================================================
"""

from __future__ import annotations

import functools
import importlib.resources
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, InputError
from ..typedconfig import parse_toml, read_toml

SPLIT_FORMAT = "ebr-test-split/1"
SPLITS = ("train", "test", "all")
MATERIAL_DIRS = ("materials", "materials_extra")
ENVMAP_DIRS = ("envmaps", "envmaps_extra")
ENVMAP_SUFFIXES = (".hdr", ".exr")
# Classes of the three sets in materials/ (materials_extra/ has them in its index.json).
_BASE_CLASSES = {"wood_floor": "wood", "painted_plaster_wall": "plaster", "Metal009": "metal"}
_DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@dataclass(frozen=True)
class TestSplit:
    """Test assets as paths relative to the data folder (``materials_extra/acg_Bark012``)."""

    materials: tuple[str, ...]
    environments: tuple[str, ...]
    source: str = "<memory>"

    def is_test(self, path: str | os.PathLike, root: str | os.PathLike | None = None) -> bool:
        """Whether ``path`` (absolute, or relative to ``root``) is one of the test assets."""
        rel = _relative(path, root)
        return rel in self.materials or rel in self.environments


def data_dir() -> Path:
    """The shared assets folder: ``$EBR_DATA_DIR``, else ``../shared/data`` beside the checkout."""
    return Path(os.environ.get("EBR_DATA_DIR") or _DEFAULT_DATA_DIR)


def _relative(path, root=None) -> str:
    root = Path(root) if root is not None else data_dir()
    p = Path(path)
    if p.is_absolute():
        try:
            p = Path(os.path.normpath(p)).relative_to(Path(os.path.normpath(root.resolve())))
        except ValueError:
            try:
                p = Path(os.path.normpath(p)).relative_to(Path(os.path.normpath(root)))
            except ValueError:
                return str(path)
    return p.as_posix()


@functools.lru_cache(maxsize=4)
def load_split(path: str | None = None) -> TestSplit:
    """The test split from ``path`` (default: the bundled ``scenes/test_split.toml``)."""
    if path is None:
        file = importlib.resources.files("ebr_mitsuba.scenes") / "test_split.toml"
        source = "scenes/test_split.toml"
        doc = parse_toml(file.read_text(), source)
    else:
        if not Path(path).is_file():
            raise InputError(f"{path}: no such split file")
        source = str(path)
        doc = read_toml(Path(path))
    table = doc.get("split")
    if not isinstance(table, dict) or table.get("name") != SPLIT_FORMAT:
        raise ConfigError(f'{source}: expected a [split] table with name = "{SPLIT_FORMAT}"')
    mats, envs = table.get("materials"), table.get("environments")
    if not (
        isinstance(mats, list)
        and isinstance(envs, list)
        and mats
        and envs
        and all(isinstance(x, str) for x in mats + envs)
    ):
        raise ConfigError(f"{source}: [split] needs non-empty string lists 'materials' and 'environments'")
    return TestSplit(tuple(mats), tuple(envs), source)


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise ConfigError(f"split {split!r}; use one of {', '.join(SPLITS)}")


def _select(paths: list[Path], root: Path, split: str, test: tuple[str, ...]) -> list[str]:
    out = []
    for p in paths:
        in_test = _relative(p, root) in test
        if split == "all" or (split == "test") == in_test:
            out.append(str(p))
    return out


def _real_assets(split: str, root, folders, keep, what: str, test: tuple[str, ...]) -> list[str]:
    _check_split(split)
    base = Path(root) if root is not None else data_dir()
    found = []
    for sub in folders:
        d = base / sub
        if d.is_dir():
            found += sorted(p for p in d.iterdir() if keep(p))
    if not found:
        raise InputError(
            f"{base}: no {what} under {', '.join(folders)}; set EBR_DATA_DIR to the shared data folder"
        )
    return _select(found, base, split, test)


def real_materials(split: str = "train", root: str | os.PathLike | None = None) -> list[str]:
    """Absolute paths of the real material sets of ``split`` (sorted; ``root``: the data folder)."""
    return _real_assets(split, root, MATERIAL_DIRS, Path.is_dir, "real material sets", load_split().materials)


def real_envmaps(split: str = "train", root: str | os.PathLike | None = None) -> list[str]:
    """Absolute paths of the real HDR maps of ``split`` (sorted; ``root``: the data folder)."""
    return _real_assets(
        split,
        root,
        ENVMAP_DIRS,
        lambda p: p.suffix.lower() in ENVMAP_SUFFIXES,
        "HDR maps",
        load_split().environments,
    )


@functools.lru_cache(maxsize=8)
def _index_classes(index: str) -> dict:
    from ..materials import read_texture_index

    return {name: entry.get("class", "unknown") for name, entry in read_texture_index(index).items()}


def material_class(path: str | os.PathLike) -> str:
    """The class of a real material set (its ``index.json`` entry), ``"unknown"`` if unlisted."""
    p = Path(path)
    if p.name in _BASE_CLASSES and p.parent.name == "materials":
        return _BASE_CLASSES[p.name]
    index = p.parent / "index.json"
    if index.is_file():
        return _index_classes(str(index)).get(p.name, "unknown")
    return "unknown"


def check_training_paths(paths, what: str, source: str, root: str | os.PathLike | None = None) -> None:
    """Refuse a training config that names a test asset (one line naming the file and the fix)."""
    split = load_split()
    for path in paths:
        if split.is_test(path, root):
            raise ConfigError(
                f"{source}: {what} names {path}, which is in the fixed test split "
                f'({split.source}); remove it from training (use split = "train")'
            )
