"""The typed-config engine (ebr_mitsuba.typedconfig): one error format, nested configs and presets,
flags and docs tables generated from the same field metadata, for every migrated config."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from ebr_mitsuba import typedconfig as tc
from ebr_mitsuba.capture import CaptureConfig
from ebr_mitsuba.commands.demo import DemoConfig
from ebr_mitsuba.commands.render import RenderConfig
from ebr_mitsuba.data import config as data_config
from ebr_mitsuba.envfit import EnvFitConfig
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.estimate.fivelight import FiveLightConfig
from ebr_mitsuba.estimate.pipeline import EstimateConfig
from ebr_mitsuba.estimate.refine import REFINE_FLAGS, RefineConfig
from ebr_mitsuba.exemplar.images import ExemplarsConfig
from ebr_mitsuba.exemplar.select import SELECT_PRESETS, SelectConfig
from ebr_mitsuba.extract.config import EXTRACT_PRESETS, ExtractConfig
from ebr_mitsuba.insert import INSERT_FLAGS, InsertConfig
from ebr_mitsuba.model import config as train_config
from ebr_mitsuba.nets import CascadeConfig, DualLossConfig, LightingNetConfig, NAFNetSize
from ebr_mitsuba.nets.mair_config import MAIRConfig, MAIRSize, UNetSize
from ebr_mitsuba.nets.nafnet import SIZE_PRESETS, SMALL_SIZE
from ebr_mitsuba.validate import ValidateConfig

MIGRATED = [
    *data_config.SECTIONS.values(),
    *data_config.MATERIAL_TYPES.values(),
    *data_config.ENVIRONMENT_TYPES.values(),
    *train_config.TABLES.values(),
    ExtractConfig,
    SelectConfig,
    RefineConfig,
    InsertConfig,
    NAFNetSize,
    LightingNetConfig,
    CascadeConfig,
    DualLossConfig,
    MAIRConfig,
    MAIRSize,
    UNetSize,
    # the command configs of tests/test_cli_configs.py
    CaptureConfig,
    EnvFitConfig,
    ExemplarsConfig,
    RenderConfig,
    ValidateConfig,
    DemoConfig,
]
# configs with required fields (no defaults): their flags are compared in tests/test_estimate_cli.py
WITH_REQUIRED = [EstimateConfig, FiveLightConfig]


@tc.config
class Inner:
    """A nested config."""

    width: int = tc.option(4, "channels", minimum=1)


INNER_PRESETS = {"tiny": Inner(width=2), "wide": Inner(width=64)}


@tc.config
class Outer:
    """A test config."""

    count: int = tc.option(3, "how many", minimum=1, maximum=10)
    rate: float = tc.option(0.5, "a rate", above=0, below=1)
    mode: str = tc.option("a", "the mode", choices=("a", "b"))
    pair: tuple[float, float] = tc.option((0.1, 0.9), "low, high", minimum=0, maximum=1, ordered=True)
    inner: Inner = tc.option(Inner(), "the nested one", presets=INNER_PRESETS, preset_kind="inner size")
    budget: float | None = tc.option(None, "seconds", above=0, shown="none")
    on: bool = tc.option(False, "a switch")


def test_unknown_key_names_file_key_and_the_allowed_keys():
    with pytest.raises(ConfigError, match=r"^f\.toml: t\.cuont: unknown key; use one of count, rate") as e:
        tc.from_dict(Outer, {"cuont": 2}, "f.toml", key="t")
    assert len(str(e.value).splitlines()) == 1
    with pytest.raises(ConfigError, match=r"f\.toml: t\.inner\.depth: unknown key; use one of width"):
        tc.from_dict(Outer, {"inner": {"depth": 2}}, "f.toml", key="t")


@pytest.mark.parametrize(
    "table, pattern",
    [
        ({"count": "3"}, r"t\.count: expected int \(a whole number\), got '3'"),
        ({"count": True}, r"t\.count: expected int"),
        ({"rate": "fast"}, r"t\.rate: expected float \(a number\), got 'fast'"),
        ({"on": 1}, r"t\.on: expected bool"),
        ({"mode": 1}, r"t\.mode: expected str"),
        ({"pair": 0.5}, r"t\.pair: expected tuple\[float, float\] \(a list\)"),
        ({"pair": [0.1]}, r"t\.pair: expected 2 values"),
        ({"inner": 3}, r"t\.inner: expected a preset name or a table \(Inner\)"),
    ],
)
def test_wrong_type(table, pattern):
    with pytest.raises(ConfigError, match=rf"^f\.toml: {pattern}"):
        tc.from_dict(Outer, table, "f.toml", key="t")


@pytest.mark.parametrize(
    "table, pattern",
    [
        ({"count": 0}, r"t\.count: must be in \[1, 10\], got 0"),
        ({"count": 11}, r"t\.count: must be in \[1, 10\], got 11"),
        ({"rate": 1.0}, r"t\.rate: must be in \(0, 1\), got 1\.0"),
        ({"rate": float("nan")}, r"t\.rate: must be finite"),
        ({"pair": [0.2, 1.5]}, r"t\.pair\[1\]: must be in \[0, 1\], got 1\.5"),
        ({"pair": [0.9, 0.1]}, r"t\.pair: got \[0\.9, 0\.1\]; low must be <= high"),
        ({"budget": -1}, r"t\.budget: must be > 0"),
        ({"inner": {"width": 0}}, r"t\.inner\.width: must be >= 1, got 0"),
    ],
)
def test_out_of_range(table, pattern):
    with pytest.raises(ConfigError, match=rf"^f\.toml: {pattern}"):
        tc.from_dict(Outer, table, "f.toml", key="t")


def test_choices_and_unknown_preset():
    with pytest.raises(ConfigError, match=r"^f\.toml: mode: got 'c'; use one of a, b$"):
        tc.from_dict(Outer, {"mode": "c"}, "f.toml")
    with pytest.raises(ConfigError, match=r"inner: unknown inner size 'huge'; use one of tiny, wide"):
        tc.from_dict(Outer, {"inner": "huge"}, "f.toml")
    # the same checks on a config built in code (class name as the place)
    with pytest.raises(ConfigError, match=r"^Outer: mode: got 'c'"):
        Outer(mode="c")


def test_nested_configs_presets_and_normalisation():
    c = tc.from_dict(Outer, {"inner": "wide", "pair": [0, 1], "rate": 1e-3}, "f.toml")
    assert c.inner is INNER_PRESETS["wide"] and c.pair == (0.0, 1.0) and isinstance(c.pair[0], float)
    assert tc.from_dict(Outer, {"inner": {"width": 7}}).inner == Inner(width=7)
    base = Outer(count=9, mode="b")
    over = tc.from_dict(Outer, {"count": 2}, base=base)
    assert (over.count, over.mode) == (2, "b")
    assert tc.from_dict(Outer, tc.to_dict(over)) == over
    # the project's nested configs: presets by name, tables field by field
    assert CascadeConfig.from_dict({"size": "small"}).size is SMALL_SIZE
    cfg = MAIRConfig.from_dict({"size": {"normal": "small", "refine": {"widths": [8, 16]}}})
    assert cfg.size.normal is SIZE_PRESETS["small"] and cfg.size.refine.widths == (8, 16)
    with pytest.raises(ConfigError, match=r"model\.size\.refine\.depth: must be >= 1"):
        MAIRConfig.from_dict({"size": {"refine": {"depth": 0}}}, "c.toml", key="model")


def test_named_presets_replace_the_train_overlays():
    assert EXTRACT_PRESETS["training"] == ExtractConfig(iters=100, max_lobes=16)
    assert SELECT_PRESETS["training"] == SelectConfig(env_mode="sg", compare_size=16)
    doc = {"data": {"train": "/d"}, "extract": {"iters": 7}}
    c = train_config.parse_config(doc, source="t.toml")
    assert c.extract_config() == dataclasses.replace(EXTRACT_PRESETS["training"], iters=7)
    assert c.select_config() == SELECT_PRESETS["training"]


def _flag_fields(cls) -> tuple[str, ...]:
    known = {RefineConfig: REFINE_FLAGS, InsertConfig: INSERT_FLAGS}
    return known.get(
        cls, tuple(f.name for f in dataclasses.fields(cls) if not dataclasses.is_dataclass(f.type))
    )


@pytest.mark.parametrize("cls", MIGRATED, ids=lambda c: c.__name__)
def test_generated_flags_default_to_the_dataclass_defaults(cls):
    hints = tc.hints(cls)
    names = [n for n in _flag_fields(cls) if not dataclasses.is_dataclass(hints[n])]
    parser = argparse.ArgumentParser()
    tc.add_flags(parser, cls, names)
    args = parser.parse_args([])
    defaults = cls()
    for f in dataclasses.fields(cls):
        if f.name in names:
            assert getattr(args, tc.flag_dest(cls, f.name)) == getattr(defaults, f.name), (
                cls.__name__,
                f.name,
            )
    assert tc.from_args(cls, args, names) == defaults
    help_text = parser.format_help()
    for name in names:
        assert tc.flag_name(cls, name) in help_text


def test_flags_parse_text_and_errors_name_the_flag():
    parser = argparse.ArgumentParser()
    tc.add_flags(parser, SelectConfig, ("coarse", "anchors", "env_mode", "env_spp"))
    args = parser.parse_args(["--coarse", "0.2,0.4", "--mode", "sg", "--spp", "8"])
    c = tc.from_args(SelectConfig, args, ("coarse", "anchors", "env_mode", "env_spp"))
    assert (c.coarse, c.env_mode, c.env_spp) == ((0.2, 0.4), "sg", 8)
    for argv, pattern in (
        (["--spp", "many"], r"^--spp 'many': give an integer$"),
        (["--spp", "0"], r"^--spp: must be >= 1, got 0$"),
        (["--anchors", "0.9,0.1"], r"^--anchors: got \[0\.9, 0\.1\]; low must be <= high$"),
        (["--mode", "path"], r"^--mode: got 'path'; use one of sg, quadrature$"),
    ):
        with pytest.raises(InputError, match=pattern):
            tc.from_args(SelectConfig, parser.parse_args(argv), ("coarse", "anchors", "env_mode", "env_spp"))
    p = argparse.ArgumentParser()
    tc.add_flags(p, Outer, ("on", "budget"), base=Outer(budget=2.0))
    assert p.parse_args([]).budget == 2.0 and p.parse_args(["--on"]).on is True
    assert tc.from_args(Outer, p.parse_args(["--budget", "none"]), ("on", "budget")).budget is None
    p = argparse.ArgumentParser()
    tc.add_flags(p, ExtractConfig, ("env_mode",), rename={"env_mode": "--extract-mode"})
    assert tc.from_args(
        ExtractConfig, p.parse_args([]), ("env_mode",), rename={"env_mode": "--extract-mode"}
    ) == (ExtractConfig())


@pytest.mark.parametrize("cls", [*MIGRATED, *WITH_REQUIRED, Outer], ids=lambda c: c.__name__)
def test_generated_tables_list_every_field(cls):
    names = [f.name for f in dataclasses.fields(cls)]
    rst = tc.table(cls)
    md = tc.markdown_table(cls)
    for name in names:
        assert f"``{name}``" in rst and f"`{name}`" in md, (cls.__name__, name)
        assert f"``{name}``" in cls.__doc__, (cls.__name__, name)
    assert len(tc.rows(cls)) == len(names)
    assert all(meaning for *_, meaning in tc.rows(cls)), f"{cls.__name__}: a field without a meaning"


def test_docs_page_and_module_docstrings_carry_the_tables():
    from ebr_mitsuba.docgen import config_page

    page = config_page()
    for _, prefix, cls, _ in __import__("ebr_mitsuba.docgen", fromlist=["x"]).config_sections():
        for f in dataclasses.fields(cls):
            assert f"`{prefix}{f.name}`" in page
    assert "`extract.iters` | `int` | `100`" in page  # the training preset's value, not the class default
    assert ".. options::" not in train_config.__doc__ and "``finetune_lr``" in train_config.__doc__
    assert ".. options::" not in data_config.__doc__ and "``fast_spp``" in data_config.__doc__


def test_every_config_class_is_frozen_and_checked():
    for cls in [*MIGRATED, *WITH_REQUIRED]:
        assert cls.__dataclass_params__.frozen, cls.__name__
        assert hasattr(cls, "__typedconfig__"), cls.__name__
    with pytest.raises(InputError, match="--refine-basis"):
        RefineConfig(basis=99)
    with pytest.raises(InputError, match="--object-scale"):
        InsertConfig(scale=2.0)
    with pytest.raises(InputError, match=r"^EstimateConfig: --fov: must be in \[10, 120\], got 5\.0"):
        EstimateConfig(flash="f", out="o", fov=5)
    with pytest.raises(InputError, match="--flash-intensity: must be > 0"):
        FiveLightConfig(lights=("a",), out="o", light_intensity=0.0)


def test_toml_files_fail_in_one_line_naming_the_file(tmp_path):
    """Every TOML reader (generate, train, the test split) goes through read_toml / parse_toml."""
    from ebr_mitsuba.data.config import load_config as load_generate
    from ebr_mitsuba.data.split import load_split
    from ebr_mitsuba.model.config import load_config as load_train
    from ebr_mitsuba.typedconfig import parse_toml, read_toml

    good = tmp_path / "good.toml"
    good.write_text("[a]\nb = 1\n")
    assert read_toml(good) == {"a": {"b": 1}} and parse_toml("x = 2", "s") == {"x": 2}
    bad = tmp_path / "bad.toml"
    bad.write_text("[a\nb = ")
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00 = 1")
    for load in (load_generate, load_train, load_split):
        with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML") as err:
            load(bad)
        assert "\n" not in str(err.value)
    for load in (load_generate, load_train, load_split):
        with pytest.raises(ConfigError, match=r"binary\.toml: not a UTF-8 text file"):
            load(binary)
