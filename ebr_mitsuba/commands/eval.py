"""Evaluate a trained model on a generated data set (the metrics of docs/conventions.md).

  ebr eval [--checkpoint CKPT] --data DIR [--json] [--limit N] [--seed S]
           [--baseline-mean TRAIN_DIR] [--baseline-oracle] [--baseline-checkpoint NAME=CKPT ...]
           [--fixed-roughness R]

For every sample the model sees only the photos; its maps are scored against the ground truth:

  per_map_rmse      RMSE per map (normal encoded (n+1)/2, diffuse, roughness, specular) and mean
  rerender_rmse     RMSE of renders under 30 seeded random light/view pairs (linear)
  ssim              SSIM of the same renders, sRGB-encoded and clipped
  seconds_per_sample  wall time of one prediction
  n                 samples evaluated

--json prints {"per_map_rmse": {...}, "rerender_rmse", "ssim", "seconds_per_sample", "n",
"per_sample": [...], "groups": {"real"|"procedural": {...}}, "classes": {CLASS: {...}},
"baselines": {...}} on stdout (CLASS: the real set's class of materials_extra/index.json, or
procedural:FAMILY).

Options (all but ``--data`` and ``--baseline-checkpoint`` are the fields of :class:`EvalConfig`:
flags, defaults and help generated from its metadata; a bad value is one line naming the flag,
exit 2):
  --checkpoint CKPT         checkpoint of `ebr train` [the shipped model]
  --data DIR                data set of `ebr generate` (the model's capture setup and grid)
  --limit N                 first N samples only [0: all]
  --seed S                  seed of the re-render light/view pairs [0]
  --baseline-mean TRAIN_DIR also score baseline (a): the per-pixel mean maps of that data set
  --baseline-oracle         also score the oracle constant: each sample's own ground-truth mean
                            maps (what a model must beat to have recovered any structure)
  --baseline-checkpoint NAME=CKPT
                            also score another checkpoint on the same samples and pairs, reported
                            as baselines[NAME] (e.g. no-exemplars=runs/noex/model.pt); repeatable
  --fixed-roughness R       exemplars at roughness R instead of the adaptive selection (ablation)

The model runs as its :class:`~ebr_mitsuba.model.predictor.Predictor`
(:func:`ebr_mitsuba.model.predict.as_predictor`; a dual-loss model as a
:class:`~ebr_mitsuba.model.predictor.LightsPredictor`), scored by :mod:`ebr_mitsuba.evaluation`.
"""

from __future__ import annotations

from ..errors import InputError
from ..typedconfig import add_flags, check, config, from_args, option
from ._common import emit_json, progress, say

NAME = "eval"
HELP = "evaluate a trained model on a generated data set (per-map RMSE, re-render RMSE, SSIM, timing)"


@config(error=InputError, cli=True)
class EvalConfig:
    """How ``ebr eval`` scores a model (a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    checkpoint: str | None = option(
        None, "checkpoint of 'ebr train'", metavar="CKPT", shown="the shipped model"
    )
    limit: int = option(0, "evaluate the first N samples only (0: all; N >= 0)", metavar="N")
    seed: int = option(0, "seed of the re-render light/view pairs", metavar="S")
    baseline_mean: str | None = option(
        None,
        "also score the per-pixel mean maps of this (training) data set",
        metavar="TRAIN_DIR",
        shown="none",
    )
    baseline_oracle: bool = option(
        False,
        "also score the oracle constant: each sample's own ground-truth mean maps "
        "(docs/conventions.md, Metrics)",
    )
    fixed_roughness: float | None = option(
        None,
        "exemplars at roughness R instead of the adaptive selection (ablation; ebrenv models)",
        minimum=0.0,
        maximum=1.0,
        metavar="R",
        shown="none",
    )

    def __post_init__(self):
        if isinstance(self.limit, int) and not isinstance(self.limit, bool) and self.limit < 0:
            raise InputError(f"--limit {self.limit}: give a count >= 0")
        check(self)


#: The fields ``ebr eval`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
EVAL_FLAGS = ("checkpoint", "limit", "seed", "baseline_mean", "baseline_oracle", "fixed_roughness")


def add_arguments(parser) -> None:
    parser.add_argument("--data", required=True, help="data set directory of 'ebr generate'")
    # The EvalConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, EvalConfig, EVAL_FLAGS)
    parser.add_argument(
        "--baseline-checkpoint",
        action="append",
        default=[],
        metavar="NAME=CKPT",
        help="also score this checkpoint on the same samples (repeatable)",
    )
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")


def _line(name: str, m: dict) -> str:
    p = m["per_map_rmse"]
    return (
        f"{name:<14} n={m['n']:<4} normal {p['normal']:.4f}  diffuse {p['diffuse']:.4f}  roughness "
        f"{p['roughness']:.4f}  specular {p['specular']:.4f}  mean {p['mean']:.4f}  rerender "
        f"{m['rerender_rmse']:.4f}  ssim {m['ssim']:.4f}"
        + (f"  {m['seconds_per_sample']:.3f} s/sample" if "seconds_per_sample" in m else "")
    )


def run(args) -> int:
    from ..evaluation.baselines import MeanMaps
    from ..evaluation.evaluate import (
        evaluate,
        group_means,
        material_class,
        material_group,
        model_predictor,
        oracle_predictor,
    )
    from ..model.predict import as_predictor, load_model

    cfg = from_args(EvalConfig, args, EVAL_FLAGS)
    others = []
    for spec in args.baseline_checkpoint:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise InputError(
                f"--baseline-checkpoint {spec!r}: write NAME=CHECKPOINT, e.g. no-exemplars=runs/noex/model.pt"
            )
        if name in ("mean_maps", "oracle_constant") or name in (o[0] for o in others):
            raise InputError(
                f"--baseline-checkpoint {spec!r}: the name {name!r} is used twice; give each its own"
            )
        others.append((name, path))
    bundle = load_model(cfg.checkpoint, expect_kind=None)
    loaded = [(name, load_model(path, expect_kind=bundle.kind)) for name, path in others]
    if bundle.kind == "dualloss" and cfg.fixed_roughness is not None:
        raise InputError("--fixed-roughness applies to ebrenv models (a dualloss model has no exemplars)")
    result = evaluate(
        model_predictor(as_predictor(bundle, cfg.fixed_roughness)),
        args.data,
        limit=cfg.limit,
        seed=cfg.seed,
        progress=progress,
    )
    result["checkpoint"] = cfg.checkpoint or "shipped"
    result["data"] = str(args.data)
    result["groups"] = group_means(result["per_sample"], material_group)
    result["classes"] = group_means(result["per_sample"], material_class)
    say(_line("model", result))
    if cfg.baseline_oracle:
        base = evaluate(oracle_predictor, args.data, limit=cfg.limit, seed=cfg.seed)
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})["oracle_constant"] = base
        say(_line("oracle constant", base))
    if cfg.baseline_mean:
        mean = MeanMaps.from_dataset(cfg.baseline_mean, bundle.config.data.max_samples)
        base = evaluate(
            lambda item, names: mean.predict(tuple(item["maps"].shape[1:])),
            args.data,
            limit=cfg.limit,
            seed=cfg.seed,
        )
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})["mean_maps"] = base
        say(_line("mean maps", base))
    for name, other in loaded:
        base = evaluate(
            model_predictor(as_predictor(other)), args.data, limit=cfg.limit, seed=cfg.seed, progress=progress
        )
        base["checkpoint"] = str(dict(others)[name])
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})[name] = base
        say(_line(name, base))
    if args.json:
        emit_json(result)
    return 0
