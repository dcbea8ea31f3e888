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

Options:
  --checkpoint CKPT         checkpoint of `ebr train` [the shipped model]
  --data DIR                data set of `ebr generate` (the model's capture setup and grid)
  --limit N                 first N samples only [all]
  --seed S                  seed of the re-render light/view pairs [0]
  --baseline-mean TRAIN_DIR also score baseline (a): the per-pixel mean maps of that data set
  --baseline-oracle         also score the oracle constant: each sample's own ground-truth mean
                            maps (what a model must beat to have recovered any structure)
  --baseline-checkpoint NAME=CKPT
                            also score another checkpoint on the same samples and pairs, reported
                            as baselines[NAME] (e.g. no-exemplars=runs/noex/model.pt); repeatable
  --fixed-roughness R       exemplars at roughness R instead of the adaptive selection (ablation)
"""

from __future__ import annotations

from ._common import emit_json, progress, say

NAME = "eval"
HELP = "evaluate a trained model on a generated data set (per-map RMSE, re-render RMSE, SSIM, timing)"


def add_arguments(parser) -> None:
    parser.add_argument("--checkpoint", default=None, help="checkpoint of 'ebr train' [the shipped model]")
    parser.add_argument("--data", required=True, help="data set directory of 'ebr generate'")
    parser.add_argument("--limit", type=int, default=0, help="evaluate the first N samples only [all]")
    parser.add_argument("--seed", type=int, default=0, help="seed of the re-render light/view pairs [0]")
    parser.add_argument(
        "--baseline-mean",
        default=None,
        metavar="TRAIN_DIR",
        help="also score the per-pixel mean maps of this (training) data set",
    )
    parser.add_argument(
        "--baseline-checkpoint",
        action="append",
        default=[],
        metavar="NAME=CKPT",
        help="also score this checkpoint on the same samples (repeatable)",
    )
    parser.add_argument(
        "--fixed-roughness",
        type=float,
        default=None,
        metavar="R",
        help="exemplars at roughness R instead of the adaptive selection (ablation)",
    )
    parser.add_argument(
        "--baseline-oracle",
        action="store_true",
        help="also score the oracle constant: each sample's own ground-truth mean maps "
        "(docs/conventions.md, Metrics)",
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
    from ..errors import InputError
    from ..evaluation.baselines import MeanMaps
    from ..evaluation.evaluate import (
        evaluate,
        group_means,
        material_class,
        material_group,
        model_predictor,
        oracle_predictor,
    )
    from ..model.predict import load_model

    if args.limit < 0:
        raise InputError(f"--limit {args.limit}: give a count >= 0")
    if args.fixed_roughness is not None and not 0.0 <= args.fixed_roughness <= 1.0:
        raise InputError(f"--fixed-roughness {args.fixed_roughness}: give a roughness in [0, 1]")
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
    bundle = load_model(args.checkpoint, expect_kind=None)
    loaded = [(name, load_model(path, expect_kind=bundle.kind)) for name, path in others]
    if bundle.kind == "dualloss" and args.fixed_roughness is not None:
        raise InputError("--fixed-roughness applies to ebrenv models (a dualloss model has no exemplars)")
    result = evaluate(
        model_predictor(bundle, args.fixed_roughness),
        args.data,
        limit=args.limit,
        seed=args.seed,
        progress=progress,
    )
    result["checkpoint"] = args.checkpoint or "shipped"
    result["data"] = str(args.data)
    result["groups"] = group_means(result["per_sample"], material_group)
    result["classes"] = group_means(result["per_sample"], material_class)
    say(_line("model", result))
    if args.baseline_oracle:
        base = evaluate(oracle_predictor, args.data, limit=args.limit, seed=args.seed)
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})["oracle_constant"] = base
        say(_line("oracle constant", base))
    if args.baseline_mean:
        mean = MeanMaps.from_dataset(args.baseline_mean, bundle.config.data.max_samples)
        base = evaluate(
            lambda item, names: mean.predict(tuple(item["maps"].shape[1:])),
            args.data,
            limit=args.limit,
            seed=args.seed,
        )
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})["mean_maps"] = base
        say(_line("mean maps", base))
    for name, other in loaded:
        base = evaluate(
            model_predictor(other), args.data, limit=args.limit, seed=args.seed, progress=progress
        )
        base["checkpoint"] = str(dict(others)[name])
        base["groups"] = group_means(base["per_sample"], material_group)
        base["classes"] = group_means(base["per_sample"], material_class)
        result.setdefault("baselines", {})[name] = base
        say(_line(name, base))
    if args.json:
        emit_json(result)
    return 0
