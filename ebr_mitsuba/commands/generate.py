"""Generate a training or test data set from a TOML config.

  ebr generate CONFIG.toml --out DIR [--count N] [--workers N] [--resume]
               [--ray ADDRESS|auto|local] [--shard-size N] [--json]

CONFIG.toml names the material and environment sources (with weights), the capture setup, the
resolution, the renderer (mitsuba with spp, or fast), the exemplar roughness sets, the camera/LDR
simulation, the seed and the count; the schema is in docs/generate.md and examples in scenes/
(near_train.toml, near_far_train.toml, five_light.toml, multiview.toml, test_real.toml). An
unknown key, a wrong type or a missing file is an error naming it (exit 2).

DIR receives dataset.json, config.toml, index.json, envs/ (SG fits of the maps), timing.json
(wall times: the only file that differs between runs) and samples/NNNNNN/ (photos, flash-only
images, exemplars, ground-truth maps, env.json, sample.json, manifest.json).

``--count`` … ``--shard-size`` are the fields of :class:`GenerateRunConfig` (flags, defaults and
help generated from its metadata; a bad value is one line naming the flag, exit 2):

  --count N       number of samples (overrides dataset.count)
  --workers N     processes (spawn), each single-threaded; the files do not depend on N
  --resume        complete (or extend to --count) an interrupted data set of the same config;
                  samples are written atomically, so a killed run leaves nothing half-written
  --ray ADDRESS   run one Ray task per shard of --shard-size samples on a cluster (ADDRESS, auto,
                  or local: a private local cluster of --workers CPUs); needs the optional extra:
                  pip install 'ebr-mitsuba[ray]'
  --json          print {"out", "count", "generated", "skipped", "seconds", "workers", "backend",
                  "samples_per_second", "samples_per_second_per_worker", "partials_removed"}

A progress bar (samples/s, ETA) is drawn on stderr; a summary line ends the run.

One run per DIR: a second `ebr generate` into a DIR in use is refused (exit 2). Killed or
stopped (SIGKILL, SIGTERM, Ctrl-C), the run takes its workers with it and keeps every complete
sample; --resume finishes the set.
"""

from __future__ import annotations

from ..data.generate import DEFAULT_SHARD_SIZE
from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, say

NAME = "generate"
HELP = "generate a data set (photos, exemplars, ground truth) from a TOML config"


@config(error=InputError, cli=True)
class GenerateRunConfig:
    """How ``ebr generate`` runs (the data set itself is the TOML config's
    :class:`~ebr_mitsuba.data.config.GenerateConfig`; a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    count: int | None = option(None, "number of samples", minimum=1, shown="dataset.count")
    workers: int = option(1, "worker processes", minimum=1)
    resume: bool = option(False, "complete an interrupted data set")
    ray: str | None = option(
        None,
        "run on a Ray cluster: ADDRESS, auto, or local (needs the package's [ray] extra)",
        metavar="ADDRESS",
        shown="none",
    )
    shard_size: int = option(DEFAULT_SHARD_SIZE, "samples per Ray task", minimum=1)


#: The fields ``ebr generate`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
GENERATE_FLAGS = ("count", "workers", "resume", "ray", "shard_size")


def add_arguments(parser) -> None:
    parser.add_argument("config", metavar="CONFIG.toml", help="data-set config (see docs/generate.md)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output data-set directory")
    # The GenerateRunConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, GenerateRunConfig, GENERATE_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    from ..data.config import load_config
    from ..data.generate import generate
    from ..fsutil import sigterm_as_exit

    run_cfg = from_args(GenerateRunConfig, args, GENERATE_FLAGS)
    data_config = load_config(args.config)
    if run_cfg.count is not None:
        data_config = data_config.with_count(run_cfg.count)
    # SIGTERM stops the workers and removes half-written files
    with sigterm_as_exit("ebr generate: terminated (SIGTERM); complete samples are kept: --resume finishes"):
        summary = generate(
            data_config,
            args.out,
            workers=run_cfg.workers,
            resume=run_cfg.resume,
            ray=run_cfg.ray,
            shard_size=run_cfg.shard_size,
            progress=True,
            say=say,
        )
    rate = summary.samples_per_second
    say(
        f"wrote {summary.out}: {summary.count} samples ({summary.generated} generated, {summary.skipped} "
        f"already there) in {summary.seconds:.1f} s, {rate:.3g} samples/s on {summary.workers} "
        f"{summary.backend} worker(s) ({rate / max(summary.workers, 1):.3g} per worker)"
    )
    if args.json:
        emit_json(summary.to_json())
    return 0
