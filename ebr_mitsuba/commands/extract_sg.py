"""Extract dominant spherical-Gaussian lobes from a directory of environment exemplars.

  ebr extract-sg EXEMPLAR_DIR --out env.json [--max-lobes 64] [--iters 400]
                 [--env-mode corrected|sg|quadrature] [--seed S] [--json]

EXEMPLAR_DIR is written by `ebr exemplars` (environment exemplars; point-light exemplars are
refused). The pipeline (quad-tree initialisation, merging, closed-form amplitudes, Adam on
λ_i(‖ŷ−y‖ + ‖log ŷ − log y‖), MS-SSIM densification, pruning) and every setting are documented
in ebr_mitsuba.extract and docs/extract-sg.md. The lobes are written as env.json (ebr-sg/1,
z-up). --json prints {"lobes", "iterations", "seconds", "rel_rmse_exemplars", "loss_history"}.

==============  ==========  ============================================================
option          default     meaning
==============  ==========  ============================================================
--max-lobes     64          lobe budget
--iters         400         Adam iterations
--env-mode      corrected   forward model in the loop (sg, quadrature, corrected)
--seed          0           pixel sampling seed
==============  ==========  ============================================================
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..extract.config import ENV_MODES, ExtractConfig
from ._common import emit_json, say

NAME = "extract-sg"
HELP = "extract dominant SG lobes from environment exemplars"

_DEFAULTS = ExtractConfig()


def add_arguments(parser) -> None:
    parser.add_argument("exemplars", metavar="EXEMPLAR_DIR", help="directory written by `ebr exemplars`")
    parser.add_argument("--out", required=True, metavar="env.json", help="output SG environment")
    parser.add_argument(
        "--max-lobes",
        type=int,
        default=_DEFAULTS.max_lobes,
        help=f"lobe budget (default {_DEFAULTS.max_lobes})",
    )
    parser.add_argument(
        "--iters", type=int, default=_DEFAULTS.iters, help=f"Adam iterations (default {_DEFAULTS.iters})"
    )
    parser.add_argument(
        "--env-mode",
        default=_DEFAULTS.env_mode,
        metavar="MODE",
        help=f"forward model: one of {', '.join(ENV_MODES)} (default {_DEFAULTS.env_mode})",
    )
    parser.add_argument("--seed", type=int, default=_DEFAULTS.seed, help=f"seed (default {_DEFAULTS.seed})")
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
    config = ExtractConfig(max_lobes=args.max_lobes, iters=args.iters, env_mode=args.env_mode, seed=args.seed)
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
