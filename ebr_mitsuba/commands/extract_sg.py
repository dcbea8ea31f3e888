"""Extract dominant spherical-Gaussian lobes from a directory of environment exemplars.

  ebr extract-sg EXEMPLAR_DIR --out env.json [--max-lobes 64] [--iters 400]
                 [--env-mode corrected|sg|quadrature] [--seed S] [--json]

EXEMPLAR_DIR is written by `ebr exemplars` (environment exemplars; point-light exemplars are
refused). The pipeline (quad-tree initialisation, merging, closed-form amplitudes, Adam on
λ_i(‖ŷ−y‖ + ‖log ŷ − log y‖), MS-SSIM densification, pruning) and every setting are documented
in ebr_mitsuba.extract and docs/extract-sg.md. The lobes are written as env.json (ebr-sg/1,
z-up). --json prints {"lobes", "iterations", "seconds", "rel_rmse_exemplars", "loss_history"}.

The options ``--max-lobes``, ``--iters``, ``--env-mode``, ``--seed`` are fields of
:class:`ebr_mitsuba.extract.ExtractConfig` (flags, defaults and help generated from its metadata).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..extract.config import ExtractConfig
from ..typedconfig import add_flags, from_args
from ._common import emit_json, say

NAME = "extract-sg"
HELP = "extract dominant SG lobes from environment exemplars"

FLAGS = ("max_lobes", "iters", "env_mode", "seed")  # the ExtractConfig fields set from the command line


def add_arguments(parser) -> None:
    parser.add_argument("exemplars", metavar="EXEMPLAR_DIR", help="directory written by `ebr exemplars`")
    parser.add_argument("--out", required=True, metavar="env.json", help="output SG environment")
    add_flags(parser, ExtractConfig, FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    from ..extract import extract_sg, read_exemplars

    out = Path(args.out)
    if out.suffix.lower() != ".json":
        raise InputError(f"{out}: the output must be a .json file (env.json)")
    if out.is_dir():
        raise InputError(f"{out}: is a directory; give a file name")
    data = read_exemplars(args.exemplars)
    if data.kind != "env":
        raise InputError(
            f"{args.exemplars}: holds {data.kind} exemplars; extract-sg needs environment exemplars "
            f"(`ebr exemplars` without --point-light)"
        )
    config = from_args(ExtractConfig, args, FLAGS)
    result = extract_sg(data.images, data.roughness, config=config, shot=data.shot, progress=True)
    result.env.save(out)
    if args.json:
        emit_json(result.to_json())
    else:
        say(
            f"wrote {out}: {result.env.num_lobes} lobes, {result.iterations} iterations in "
            f"{result.seconds:.1f} s; "
            f"exemplar relative RMSE {result.rel_rmse_exemplars:.4f}"
        )
    return 0
