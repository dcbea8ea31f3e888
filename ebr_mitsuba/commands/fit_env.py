"""Fit a spherical-Gaussian mixture to an equirectangular environment map.

  ebr fit-env MAP --lobes K --out env.json [--iters N] [--height H] [--lr LR]
              [--log-weight B] [--json]

MAP is an equirectangular .hdr/.exr (Mitsuba's y-up layout; the lobes are written in our z-up
world, format ebr-sg/1). The fit minimises a solid-angle weighted squared error plus B times a
log-space term, with Adam in Dr.Jit, on the map area-resampled to H x 2H cells (method and error
definitions: ebr_mitsuba.envfit). The fit error is reported on stderr (and with --json on stdout:
{"out", "lobes", "error": {"rel_l1", "rel_rmse", "log_rmse", "energy", "fit": {...}},
"initial_error", "loss_history", "seconds", "settings"}).

The options ``--lobes``, ``--iters``, ``--height``, ``--lr``, ``--log-weight`` are fields of
:class:`ebr_mitsuba.envfit.EnvFitConfig` (flags, defaults and help generated from its metadata);
a bad value is one line naming the flag (exit 2).
"""

from __future__ import annotations

from ..envfit import ENVFIT_FLAGS, EnvFitConfig
from ..typedconfig import add_flags, from_args
from ._common import emit_json, say

NAME = "fit-env"
HELP = "fit SG lobes to an equirectangular environment map"


def add_arguments(parser) -> None:
    parser.add_argument("map", metavar="MAP", help="equirectangular .hdr or .exr")
    parser.add_argument("--out", required=True, metavar="env.json", help="output SG environment")
    # The EnvFitConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, EnvFitConfig, ENVFIT_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def config_from_args(args) -> EnvFitConfig:
    """The :class:`~ebr_mitsuba.envfit.EnvFitConfig` of the parsed options (InputError if bad)."""
    return from_args(EnvFitConfig, args, ENVFIT_FLAGS)


def run(args) -> int:
    from ..envfit import fit_sg
    from ..envmap import load_equirect
    from ._common import progress

    cfg = config_from_args(args)
    emap = load_equirect(args.map)
    bar = progress(total=max(cfg.iterations, 1), desc="fit-env", unit="it", disable=None)
    last = [0]

    def tick(it, loss):
        bar.update(it - last[0])
        last[0] = it
        bar.set_postfix(loss=f"{loss:.4g}")

    result = fit_sg(emap, cfg, progress=tick)
    bar.close()
    result.env.save(args.out)
    e = result.error
    say(
        f"wrote {args.out}: {result.env.num_lobes} lobes in {result.seconds:.1f} s; fit error "
        f"(solid-angle weighted, {result.settings['eval_height']} rows): relative L1 {e['rel_l1']:.3f}, "
        f"relative RMSE {e['rel_rmse']:.3f}, log RMSE {e['log_rmse']:.3f}, energy {e['energy']:+.3f} "
        f"(at the fit's {result.settings['height']} rows: relative L1 {e['fit']['rel_l1']:.3f})"
    )
    if args.json:
        emit_json({"out": str(args.out), **result.to_json()})
    return 0
