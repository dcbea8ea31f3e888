"""``ebr capture``, ``fit-env``, ``exemplars``, ``render``, ``validate``, ``demo``, ``gallery``,
``generate``, ``train``, ``eval``, ``dataset sheet`` and ``bench`` build their options from typed configs
(issue 11): the defaults ``--help`` shows and the parser holds are the configs' defaults, every
option but the command's own inputs is a config field, the config built from no flags is the
config's default, and a bad value is one line, exit 2. Nothing is rendered here: the commands fail
on the bad value before any work.
"""

from __future__ import annotations

import dataclasses
import re

import pytest
from cli_help import help_entries, subparser

from ebr_mitsuba import typedconfig as tc
from ebr_mitsuba.capture import CAPTURE_FLAGS, CaptureConfig
from ebr_mitsuba.cli import main
from ebr_mitsuba.commands.bench import BENCH_FLAGS, BenchConfig
from ebr_mitsuba.commands.dataset import SHEET_FLAGS, SheetConfig
from ebr_mitsuba.commands.demo import DEMO_FLAGS, DemoConfig
from ebr_mitsuba.commands.eval import EVAL_FLAGS, EvalConfig
from ebr_mitsuba.commands.gallery import GALLERY_FLAGS, GalleryConfig
from ebr_mitsuba.commands.generate import GENERATE_FLAGS, GenerateRunConfig
from ebr_mitsuba.commands.render import RENDER_FLAGS, RenderConfig
from ebr_mitsuba.commands.train import TRAIN_FLAGS, TrainRunConfig
from ebr_mitsuba.envfit import ENVFIT_FLAGS, EnvFitConfig
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.exemplar.images import EXEMPLARS_FLAGS, ExemplarsConfig
from ebr_mitsuba.validate import VALIDATE_FLAGS, ValidateConfig

GLOBAL = {"--help", "--json", "--variant", "--deterministic"}

# command: (config, its flag fields, the options the command declares itself, minimal argv)
COMMANDS = {
    "capture": (
        CaptureConfig,
        CAPTURE_FLAGS,
        {"--material", "--env", "--setup", "--out"},
        ["--material", "m", "--env", "e", "--setup", "near", "--out", "o"],
    ),
    "fit-env": (EnvFitConfig, ENVFIT_FLAGS, {"--out"}, ["map.hdr", "--out", "env.json"]),
    "exemplars": (ExemplarsConfig, EXEMPLARS_FLAGS, {"--env", "--out"}, ["--out", "o"]),
    "render": (RenderConfig, RENDER_FLAGS, {"--out", "-D"}, ["default", "--out", "o.exr"]),
    "validate": (ValidateConfig, VALIDATE_FLAGS, {"--case", "--markdown"}, []),
    "demo": (DemoConfig, DEMO_FLAGS, set(), []),
    "gallery": (GalleryConfig, GALLERY_FLAGS, set(), ["photos"]),
    "generate": (GenerateRunConfig, GENERATE_FLAGS, {"--out"}, ["c.toml", "--out", "o"]),
    "train": (TrainRunConfig, TRAIN_FLAGS, set(), ["c.toml"]),
    "eval": (EvalConfig, EVAL_FLAGS, {"--data", "--baseline-checkpoint"}, ["--data", "d"]),
    "dataset sheet": (SheetConfig, SHEET_FLAGS, {"--out"}, ["d", "--out", "s.png"]),
    "bench": (BenchConfig, BENCH_FLAGS, set(), []),
}


def _shown(f: dataclasses.Field) -> str:
    """A field's default as ``--help`` writes it: the table's text, a string unquoted, a sequence
    comma-separated."""
    value = f.default
    if isinstance(value, tuple) and tc.meta_of(f).shown is None:
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return tc.default_text(f).strip('"')


@pytest.mark.parametrize("name", COMMANDS)
def test_every_option_is_a_config_field_or_an_input(name):
    cls, flags, own, _ = COMMANDS[name]
    options = {
        s for a in subparser(name)._actions for s in a.option_strings if s.startswith("-") and s != "-h"
    }
    generated = {tc.flag_name(cls, n) for n in flags}
    assert options - GLOBAL - own == generated, name
    assert not own & generated


@pytest.mark.parametrize("name", COMMANDS)
def test_help_and_parser_defaults_are_the_config_defaults(name):
    cls, flags, _, argv = COMMANDS[name]
    parser = subparser(name)
    args = parser.parse_args(argv)
    entries = help_entries(parser)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for field_name in flags:
        f = fields[field_name]
        flag, dest = tc.flag_name(cls, field_name), tc.flag_dest(cls, field_name)
        assert parser.get_default(dest) == f.default, (name, flag)
        assert getattr(args, dest) == f.default, (name, flag)
        shown = re.search(r"\[([^\]]*)\]$", entries[flag])
        assert shown, (name, flag, entries[flag])
        assert shown.group(1) == _shown(f), (name, flag, shown.group(1))
        assert tc.meta_of(f).meaning and tc.meta_of(f).meaning in entries[flag]
    # the config of no flags is the config's own default (no default restated by the command)
    assert tc.from_args(cls, args, flags) == cls()


def test_defaults_spelled_out():
    """The values users knew before the flags were generated (a user's command line still means
    the same)."""
    entries = {name: help_entries(subparser(name)) for name in COMMANDS}
    assert "[64]" in entries["capture"]["--spp"] and "[256]" in entries["capture"]["--res"]
    assert "[direct]" in entries["capture"]["--integrator"] and "[1]" in entries["capture"]["--env-scale"]
    assert CaptureConfig() == CaptureConfig(spp=64, res=256, seed=0, integrator="direct", env_scale=1.0)
    assert EnvFitConfig() == EnvFitConfig(lobes=32, iterations=400, height=64, lr=0.03, log_weight=0.1)
    assert "[400]" in entries["fit-env"]["--iters"]
    assert ExemplarsConfig() == ExemplarsConfig(
        roughness=(0.1, 0.3, 0.6, 0.9), renderer="mitsuba", res=256, spp=256, seed=0
    )
    assert "[0.1,0.3,0.6,0.9]" in entries["exemplars"]["--roughness"]
    assert RenderConfig() == RenderConfig(spp=None, seed=0)
    assert ValidateConfig().spp == 131072 and "[131072]" in entries["validate"]["--spp"]
    assert DemoConfig() == DemoConfig(out="ebr-demo", res=256, spp=64, refine_steps=100)
    assert "[256]" in entries["demo"]["--res"]
    assert GalleryConfig() == GalleryConfig(docs="docs", checkpoint=None, refine_steps=0)
    assert "[docs]" in entries["gallery"]["--docs"] and "[0]" in entries["gallery"]["--refine-steps"]
    assert GenerateRunConfig() == GenerateRunConfig(
        count=None, workers=1, resume=False, ray=None, shard_size=4
    )
    assert "[1]" in entries["generate"]["--workers"] and "[4]" in entries["generate"]["--shard-size"]
    assert TrainRunConfig() == TrainRunConfig(out=None, resume=False, export=None)
    assert "[runs/<config name>]" in entries["train"]["--out"]
    assert SheetConfig().samples == 16 and "[16]" in entries["dataset sheet"]["--samples"]
    assert BenchConfig() == BenchConfig(out=None, quick=False)
    assert EvalConfig() == EvalConfig(
        checkpoint=None, limit=0, seed=0, baseline_mean=None, baseline_oracle=False, fixed_roughness=None
    )
    assert "[the shipped model]" in entries["eval"]["--checkpoint"] and "[0]" in entries["eval"]["--limit"]


def test_flags_set_the_fields():
    cfg = tc.from_args(
        ExemplarsConfig,
        subparser("exemplars").parse_args(
            ["--out", "o", "--roughness", "0.2,0.5", "--point-light", "--renderer", "fast", "--res", "32"]
        ),
        EXEMPLARS_FLAGS,
    )
    assert cfg == ExemplarsConfig(roughness=(0.2, 0.5), point_light=True, renderer="fast", res=32)
    args = subparser("capture").parse_args(
        COMMANDS["capture"][3] + ["--spp", "4", "--integrator", "path", "--env-scale", "2.5"]
    )
    assert tc.from_args(CaptureConfig, args, CAPTURE_FLAGS) == CaptureConfig(
        spp=4, integrator="path", env_scale=2.5
    )
    args = subparser("fit-env").parse_args(COMMANDS["fit-env"][3] + ["--iters", "7", "--log-weight", "0"])
    assert tc.from_args(EnvFitConfig, args, ENVFIT_FLAGS) == EnvFitConfig(iterations=7, log_weight=0.0)
    args = subparser("render").parse_args(COMMANDS["render"][3] + ["--spp", "8"])
    assert tc.from_args(RenderConfig, args, RENDER_FLAGS).spp == 8
    args = subparser("demo").parse_args(["--res", "32", "--refine-steps", "0", "--checkpoint", "m.pt"])
    assert tc.from_args(DemoConfig, args, DEMO_FLAGS) == DemoConfig(res=32, refine_steps=0, checkpoint="m.pt")
    args = subparser("generate").parse_args(
        COMMANDS["generate"][3] + ["--count", "5", "--workers", "2", "--resume", "--ray", "auto"]
    )
    assert tc.from_args(GenerateRunConfig, args, GENERATE_FLAGS) == GenerateRunConfig(
        count=5, workers=2, resume=True, ray="auto"
    )
    args = subparser("train").parse_args(["c.toml", "--out", "r", "--resume", "--export", "m.pt"])
    assert tc.from_args(TrainRunConfig, args, TRAIN_FLAGS) == TrainRunConfig(
        out="r", resume=True, export="m.pt"
    )
    args = subparser("gallery").parse_args(["photos", "--docs", "d", "--refine-steps", "3"])
    assert tc.from_args(GalleryConfig, args, GALLERY_FLAGS) == GalleryConfig(docs="d", refine_steps=3)
    args = subparser("dataset sheet").parse_args(COMMANDS["dataset sheet"][3] + ["--samples", "3"])
    assert tc.from_args(SheetConfig, args, SHEET_FLAGS) == SheetConfig(samples=3)
    args = subparser("bench").parse_args(["renderer", "--out", "b", "--quick"])
    assert tc.from_args(BenchConfig, args, BENCH_FLAGS) == BenchConfig(out="b", quick=True)
    args = subparser("eval").parse_args(
        ["--data", "d", "--limit", "2", "--baseline-oracle", "--fixed-roughness", "0.5"]
    )
    assert tc.from_args(EvalConfig, args, EVAL_FLAGS) == EvalConfig(
        limit=2, baseline_oracle=True, fixed_roughness=0.5
    )


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["capture", *COMMANDS["capture"][3], "--spp", "0"], "--spp: must be >= 1, got 0"),
        (["capture", *COMMANDS["capture"][3], "--env-scale", "-1"], "--env-scale: must be >= 0"),
        (["capture", *COMMANDS["capture"][3], "--res", "many"], "--res 'many': give an integer"),
        (["fit-env", "map.hdr", "--out", "e.json", "--lobes", "0"], "--lobes: must be in [1, 512], got 0"),
        (["fit-env", "map.hdr", "--out", "e.json", "--lr", "0"], "--lr: must be > 0"),
        (["exemplars", "--out", "o", "--roughness", "0.1,2"], "--roughness[1]: must be in [0, 1]"),
        (["exemplars", "--out", "o", "--roughness", "0.3,0.3"], "a value repeats"),
        (["exemplars", "--out", "o", "--renderer", "pbrt"], "--renderer: got 'pbrt'; use one of"),
        (["render", "default", "--out", "o.exr", "--spp", "0"], "--spp: must be >= 1, got 0"),
        (["render", "default", "--out", "o.exr", "--seed", "-1"], "--seed: must be in [0, 4294967295]"),
        (["validate", "--spp", "0"], "--spp: must be >= 1, got 0"),
        (["validate", "--seed", "x"], "--seed 'x': give an integer"),
        (["demo", "--spp", "0"], "--spp: must be >= 1, got 0"),
        (["demo", "--refine-steps", "-1"], "--refine-steps: must be >= 0"),
        (["gallery", "photos", "--refine-steps", "-1"], "--refine-steps: must be >= 0, got -1"),
        (["generate", "c.toml", "--out", "o", "--workers", "0"], "--workers: must be >= 1, got 0"),
        (["generate", "c.toml", "--out", "o", "--count", "0"], "--count: must be >= 1, got 0"),
        (["generate", "c.toml", "--out", "o", "--shard-size", "x"], "--shard-size 'x': give an integer"),
        (["dataset", "sheet", "d", "--out", "s.png", "--samples", "0"], "--samples: must be >= 1, got 0"),
        (["eval", "--data", "d", "--fixed-roughness", "2"], "--fixed-roughness: must be in [0, 1], got 2"),
        (["eval", "--data", "d", "--limit", "-1"], "--limit -1: give a count >= 0"),
    ],
)
def test_bad_value_is_one_line_exit_2(tmp_path, monkeypatch, capsys, argv, needle):
    monkeypatch.chdir(tmp_path)  # relative outputs land here, and none may appear
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and needle in lines[0], err
    assert "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_library_functions_take_the_config():
    """capture, fit_sg, run_case and render_exemplars take their config (or its fields as
    keywords); a bad field is the config's error before any work."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.envfit import fit_sg
    from ebr_mitsuba.validate import run_case

    with pytest.raises(InputError, match=r"^CaptureConfig: spp: must be >= 1, got 0$"):
        capture("procedural:wood:1", None, "near", "unused", spp=0)
    with pytest.raises(InputError, match="integrator"):
        capture("procedural:wood:1", None, "near", "unused", CaptureConfig(), integrator="bdpt")
    with pytest.raises(ConfigError, match=r"^EnvFitConfig: lobes: must be in \[1, 512\]"):
        fit_sg(None, lobes=0)
    with pytest.raises(TypeError, match="EnvFitConfig"):
        fit_sg(None, 8)  # a positional lobe count is not a config
    with pytest.raises(InputError, match="ValidateConfig: spp"):
        run_case(None, spp=0)
    with pytest.raises(InputError, match=r"^ExemplarsConfig: res: must be in \[16, 4096\], got 8$"):
        ExemplarsConfig(res=8)
