"""Train the EBREnv networks, the dual-loss estimator or the MAIR multi-view networks from a TOML config.

  ebr train CONFIG.toml [--out DIR] [--resume] [--export FILE] [--json]

The config (schema: docs/train.md, defaults in ebr_mitsuba/model/config.py) names the data set
(`ebr generate`), the networks, the steps per phase and the losses. The run writes into DIR
(default: runs/<config name>):

  config.json    the config as trained (after defaults)
  log.csv        phase, step, loss, per-term losses, learning rate, samples/s, seconds
  last.pt        the latest checkpoint (weights, config, git hash, step, optimizer state)
  model.pt       the final checkpoint
  summary.json   per-phase steps, final losses and seconds
  cache/         per-sample exemplar selections and extracted SGs (reused by --resume)

Options (``--out``, ``--resume`` and ``--export`` are the fields of :class:`TrainRunConfig`: flags,
defaults and help generated from its metadata):
  --out DIR      output directory (new, empty, or a run stopped before its first checkpoint,
                 which starts over; a run with a checkpoint needs --resume)
  --resume       continue the run in DIR from last.pt (same config); a finished run only
                 rewrites model.pt (and --export); without a checkpoint yet, start over
  --export FILE  also write the deployable copy of model.pt (float16 weights, no optimizer
                 state): how ebr_mitsuba/models/ebrenv_real.pt is made
  --json         print summary.json on stdout

Data-parallel: `torchrun --nproc_per_node N -m ebr_mitsuba.cli train CONFIG.toml --out DIR`
(gloo on CPU, NCCL on CUDA; rank 0 writes). CUDA is used when present ([train].device = "auto").
A progress bar with the loss and samples/s runs on stderr (rank 0 only under torchrun).

Reliability (docs/reliability.md): one run per DIR (a second is refused, exit 2); every sample
is checked against its manifest before use (a damaged file is refused by name, exit 2); a kill
at any point leaves DIR resumable; the same seed gives the same weights on one machine.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, progress, say

NAME = "train"
HELP = "train the networks from a TOML config (two stages, checkpoints, resume, DDP)"


@config(error=InputError, cli=True)
class TrainRunConfig:
    """How ``ebr train`` runs (the training itself is the TOML config's
    :class:`~ebr_mitsuba.model.config.TrainConfig`; a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    out: str | None = option(None, "output directory", metavar="DIR", shown="runs/<config name>")
    resume: bool = option(False, "continue the run in --out from last.pt")
    export: str | None = option(
        None, "also write a deployable float16 copy of the final model to FILE", metavar="FILE", shown="none"
    )


#: The fields ``ebr train`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
TRAIN_FLAGS = ("out", "resume", "export")


def add_arguments(parser) -> None:
    parser.add_argument("config", help="training config (TOML), e.g. configs/train_small.toml")
    # The TrainRunConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, TrainRunConfig, TRAIN_FLAGS)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")


def run(args) -> int:
    from ..fsutil import sigterm_as_exit
    from ..model.checkpoint import export_model
    from ..model.config import load_config
    from ..train.ddp import shutdown
    from ..train.trainer import Trainer

    run_cfg = from_args(TrainRunConfig, args, TRAIN_FLAGS)
    train_config = load_config(args.config)
    if run_cfg.export and not Path(run_cfg.export).resolve().parent.is_dir():
        raise InputError(
            f"--export {run_cfg.export}: its folder does not exist; create it or choose another path"
        )
    out = Path(run_cfg.out) if run_cfg.out else Path("runs") / Path(args.config).stem
    # SIGTERM: the atomic checkpoint write in progress removes its temporary, the lock is released
    with sigterm_as_exit("ebr train: terminated (SIGTERM); --resume continues from the last checkpoint"):
        trainer = Trainer(train_config, out, resume=run_cfg.resume, log=say, progress=progress)
        try:
            summary = trainer.run()
        finally:
            trainer.close()
            shutdown(trainer.dist)
    if trainer.dist.main:
        say(f"wrote {out / 'model.pt'} ({summary.get('seconds', 0):.0f} s, {summary.get('samples')} samples)")
        if run_cfg.export:
            path = export_model(out / "model.pt", run_cfg.export)
            say(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, float16)")
        if args.json:
            emit_json(summary)
    return 0
