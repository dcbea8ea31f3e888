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
from ._common import emit_json, say

NAME = "generate"
HELP = "generate a data set (photos, exemplars, ground truth) from a TOML config"


def add_arguments(parser) -> None:
    parser.add_argument("config", metavar="CONFIG.toml", help="data-set config (see docs/generate.md)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output data-set directory")
    parser.add_argument("--count", type=int, default=None, help="number of samples (default: dataset.count)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--resume", action="store_true", help="complete an interrupted data set")
    parser.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="run on a Ray cluster: ADDRESS, auto, or local (needs ebr-mitsuba[ray])",
    )
    parser.add_argument(
        "--shard-size",
        type=int,
        default=DEFAULT_SHARD_SIZE,
        help=f"samples per Ray task (default {DEFAULT_SHARD_SIZE})",
    )
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    from ..data.config import load_config
    from ..data.generate import generate
    from ..fsutil import sigterm_as_exit

    config = load_config(args.config)
    if args.count is not None:
        config = config.with_count(args.count)
    # SIGTERM stops the workers and removes half-written files
    with sigterm_as_exit("ebr generate: terminated (SIGTERM); complete samples are kept: --resume finishes"):
        summary = generate(
            config,
            args.out,
            workers=args.workers,
            resume=args.resume,
            ray=args.ray,
            shard_size=args.shard_size,
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
