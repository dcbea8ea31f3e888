"""``ebr estimate``'s flags are generated from EstimateConfig, ShadingNormalsConfig, RefineConfig,
FiveLightConfig and MultiViewConfig: the defaults ``--help`` shows and the parser holds are the
fields' defaults (a flag two configs share shows the first one's help), and the configs built from
the flags are the configs' own (no default restated in the command). Nothing is estimated here:
these tests only parse."""

from __future__ import annotations

import dataclasses
import re

import pytest
from cli_help import help_entries, subparser
from cli_run import nonblank_lines

from ebr_mitsuba import typedconfig as tc
from ebr_mitsuba.cli import main
from ebr_mitsuba.commands import estimate as cmd
from ebr_mitsuba.estimate.fivelight import FIVELIGHT_FLAGS, FiveLightConfig
from ebr_mitsuba.estimate.multiview import MULTIVIEW_FLAGS, MultiViewConfig
from ebr_mitsuba.estimate.pipeline import ESTIMATE_FLAGS, EstimateConfig
from ebr_mitsuba.estimate.refine import REFINE_FLAGS, RefineConfig
from ebr_mitsuba.estimate.shading_normals import SHADING_FLAGS, ShadingNormalsConfig

CONFIGS = (
    (EstimateConfig, ESTIMATE_FLAGS),
    (ShadingNormalsConfig, SHADING_FLAGS),
    (RefineConfig, REFINE_FLAGS),
    (FiveLightConfig, FIVELIGHT_FLAGS),
    (MultiViewConfig, MULTIVIEW_FLAGS),
)
NOT_CONFIG = {"--help", "--json", "--variant", "--deterministic"}  # options of the command itself


def _field(cls, name) -> dataclasses.Field:
    return next(f for f in dataclasses.fields(cls) if f.name == name)


def test_every_option_is_a_config_field_and_every_field_a_flag():
    parser = subparser("estimate")
    options = {s for a in parser._actions for s in a.option_strings if s.startswith("--")}
    flags = {tc.flag_name(cls, n) for cls, names in CONFIGS for n in names}
    bool_negations = {
        "--no-" + tc.flag_name(cls, name)[2:]
        for cls, name in (
            (EstimateConfig, "flash_fit"),
            (EstimateConfig, "shading_normals"),
            (EstimateConfig, "highlight_tilt"),
            (EstimateConfig, "roughness_pattern"),
            (EstimateConfig, "drop_horizon_lobes"),
            (MultiViewConfig, "view_fit"),
            (MultiViewConfig, "pixel_albedo"),
            (MultiViewConfig, "azimuthal_env"),
        )
    }  # --no-flash-fit, --no-shading-normals, --no-highlight-tilt, --no-roughness-pattern,
    # --no-drop-horizon-lobes, --no-view-fit, --no-pixel-albedo, --no-azimuthal-env
    assert options - NOT_CONFIG - bool_negations == flags
    assert {"--no-flash-fit", "--no-shading-normals", "--drop-horizon-lobes", "--no-view-fit"} <= options
    assert "--no-pixel-albedo" in options and "--no-azimuthal-env" in options
    assert "--no-roughness-pattern" in options and "--no-highlight-tilt" in options
    # every field of EstimateConfig (but the nested RefineConfig and ShadingNormalsConfig) and
    # FiveLightConfig is a flag
    assert set(ESTIMATE_FLAGS) == {f.name for f in dataclasses.fields(EstimateConfig)} - {"refine", "shading"}
    assert set(FIVELIGHT_FLAGS) == {f.name for f in dataclasses.fields(FiveLightConfig)}
    assert set(MULTIVIEW_FLAGS) == {f.name for f in dataclasses.fields(MultiViewConfig)}


def test_help_and_parser_defaults_are_the_config_defaults():
    """The acceptance line of issue 11: `ebr estimate --help` shows the defaults of EstimateConfig
    (and RefineConfig, FiveLightConfig); the parser's defaults are the fields' defaults."""
    parser = subparser("estimate")
    args = parser.parse_args(["--out", "o"])
    entries = help_entries(parser)
    checked, seen = 0, set()
    for cls, names in CONFIGS:
        for name in names:
            f = _field(cls, name)
            flag, dest = tc.flag_name(cls, name), tc.flag_dest(cls, name)
            assert flag in entries, (cls.__name__, flag)
            if f.default is dataclasses.MISSING:  # flash, out, lights, views: no default
                assert parser.get_default(dest) is None, flag
                assert not re.search(r"\[[^\]]*\]$", entries[flag]), (flag, entries[flag])
                continue
            assert parser.get_default(dest) == f.default, (cls.__name__, name)
            assert getattr(args, dest) == f.default, (cls.__name__, name)
            if flag in seen and cls is MultiViewConfig:  # a shared flag: the help of the first config
                continue
            seen.add(flag)
            shown = re.search(r"\[([^\]]*)\]$", entries[flag])
            assert shown, (flag, entries[flag])
            expected = tc.default_text(f)
            assert shown.group(1) in (expected, expected.strip('"')), (flag, shown.group(1), expected)
            checked += 1
    assert checked >= 18
    # the values behind the brackets, spelled out for the main ones
    assert "[45]" in entries["--fov"] and EstimateConfig.__dataclass_fields__["fov"].default == 45.0
    assert "[2048]" in entries["--max-size"] and "[0.02]" in entries["--max-shift"]
    assert "[0]" in entries["--refine-steps"] and "[sg]" in entries["--render-mode"]
    assert "[true]" in entries["--flash-fit"]


def test_configs_from_the_flags_are_the_config_defaults():
    parser = subparser("estimate")
    args = parser.parse_args(["--flash", "f.exr", "--out", "o"])
    assert cmd.estimate_config(args) == EstimateConfig(flash="f.exr", out="o")
    assert cmd.refine_config(args) == RefineConfig()
    args = parser.parse_args(["--lights", "a", "b", "c", "d", "e", "--out", "o"])
    assert cmd.fivelight_config(args) == FiveLightConfig(lights=("a", "b", "c", "d", "e"), out="o")
    cmd.check_light_flags(args)  # the defaults of the flash/no-flash options count as not given
    args = parser.parse_args(["--views", "d", "--out", "o"])
    assert cmd.multiview_config(args) == MultiViewConfig(views="d", out="o")
    assert cmd.check_view_flags(args) == MultiViewConfig(views="d", out="o")


def test_flags_set_the_fields():
    parser = subparser("estimate")
    argv = ["--flash", "f.exr", "--noflash", "n.exr", "--out", "o", "--fov", "50", "--max-shift", "0.1"]
    argv += ["--flash-intensity", "3", "--max-size", "512", "--no-flash-fit", "--exposure-ratio", "2"]
    argv += [
        "--refine-steps",
        "7",
        "--refine-lr",
        "0.05",
        "--render-mode",
        "quadrature",
        "--refine-basis",
        "2",
    ]
    argv += ["--refine-seconds", "9", "--refine-lobes", "--checkpoint", "m.pt", "--saturation-level", "0.9"]
    argv += ["--normal-gain", "0.9", "--relief-gain", "1.25"]
    cfg = cmd.estimate_config(parser.parse_args(argv))
    assert cfg == EstimateConfig(
        flash="f.exr",
        noflash="n.exr",
        out="o",
        checkpoint="m.pt",
        refine=RefineConfig(steps=7, lr=0.05, mode="quadrature", basis=2, seconds=9.0, lobes=True),
        shading=ShadingNormalsConfig(map_gain=0.9, relief_gain=1.25),
        exposure_ratio=2.0,
        fov=50.0,
        max_shift=0.1,
        saturation_level=0.9,
        flash_intensity=3.0,
        max_size=512,
        flash_fit=False,
    )
    args = parser.parse_args(["--lights", "d", "--out", "o", "--flash-intensity", "40", "--max-size", "256"])
    assert cmd.fivelight_config(args) == FiveLightConfig(
        lights=("d",), out="o", light_intensity=40.0, max_size=256
    )
    argv = ["--views", "d", "--out", "o", "--flash-intensity", "40", "--max-size", "256"]
    argv += ["--checkpoint", "m.pt", "--saturation-level", "0.9"]
    assert cmd.multiview_config(parser.parse_args(argv)) == MultiViewConfig(
        views="d", out="o", checkpoint="m.pt", flash_intensity=40.0, saturation_level=0.9, max_size=256
    )


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--fov", "wide"], "--fov 'wide': give a number"),
        (["--fov", "5"], "--fov: must be in [10, 120], got 5.0"),
        (["--max-size", "1.5"], "--max-size '1.5': give an integer"),
        (["--flash-intensity", "-1"], "--flash-intensity: must be > 0"),
        (["--flash-intensity", "inf"], "--flash-intensity: must be finite"),
        (["--exposure-ratio", "0"], "--exposure-ratio: must be > 0"),
        (["--render-mode", "path"], "--render-mode: got 'path'; use one of sg, quadrature"),
        (["--refine-basis", "99"], "--refine-basis: must be in [0, 8]"),
        (["--relief-gain", "3"], "--relief-gain: must be in [0, 2]"),
        (["--normal-gain", "-0.1"], "--normal-gain: must be in [0, 1]"),
    ],
)
def test_bad_values_exit_2_naming_the_flag(tmp_path, capsys, extra, needle):
    out = tmp_path / "out"
    code = main(["estimate", "--flash", str(tmp_path / "f.exr"), "--out", str(out), *extra])
    err = capsys.readouterr().err
    lines = nonblank_lines(err)
    assert code == 2 and len(lines) == 1 and needle in lines[0], err
    assert not out.exists()


@pytest.mark.parametrize(
    "extra", [["--refine-basis", "2"], ["--max-shift", "0.1"], ["--refine-lobes"], ["--relief-gain", "1"]]
)
def test_flash_noflash_options_are_refused_with_lights(tmp_path, capsys, extra):
    out = tmp_path / "out"
    code = main(["estimate", "--lights", str(tmp_path), "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2 and f"{extra[0]} does not apply to --lights" in err, err
    # an option given at its default value is not refused
    args = subparser("estimate").parse_args(
        ["--lights", "d", "--out", "o", "--fov", "45", "--refine-steps", "0"]
    )
    cmd.check_light_flags(args)
    # --no-flash-fit applies to both: for --lights it keeps the network's maps
    args = subparser("estimate").parse_args(["--lights", "d", "--out", "o", "--no-flash-fit"])
    assert cmd.check_light_flags(args).flash_fit is False


def test_required_out_is_an_argparse_error():
    with pytest.raises(SystemExit) as exc:
        subparser("estimate").parse_args(["--flash", "f.exr"])
    assert exc.value.code == 2


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--refine-basis", "2"], "--refine-basis does not apply to --views"),
        (["--max-shift", "0.1"], "--max-shift does not apply to --views"),
        (["--no-flash-fit"], "--no-flash-fit does not apply to --views"),
        (["--normal-gain", "0.8"], "--normal-gain does not apply to --views"),
        (["--lights", "a"], "--views and --lights are two captures"),
        (["--flash", "f.exr"], "--views and --flash are two captures"),
    ],
)
def test_other_options_are_refused_with_views(tmp_path, capsys, extra, needle):
    out = tmp_path / "out"
    code = main(["estimate", "--views", str(tmp_path), "--out", str(out), *extra])
    lines = nonblank_lines(capsys.readouterr().err)
    assert code == 2 and len(lines) == 1 and needle in lines[0], lines
    assert not out.exists()
    # an option given at its default value is not refused
    args = subparser("estimate").parse_args(["--views", "d", "--out", "o", "--fov", "45"])
    cmd.check_view_flags(args)
