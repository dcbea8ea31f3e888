"""The five-light loss ablation as ``ebr bench fivelight`` records it (``fivelight.json``) and as
``models.md`` and ``fivelight.md`` show it: the runs' figures beside the dual-loss paper's
(a module of its own so that :mod:`.models` and :mod:`.fivelight` both read it without importing
each other)."""

from __future__ import annotations

import json
from pathlib import Path

ABLATION_FILE = "fivelight.json"  # the ablation's figures, for models.md (:func:`models_section`)
# The dual-loss paper (Boss et al. 2018), RMSE on its 29 real materials (another test set).
PAPER = {"base colour": 0.0808, "normal": 0.0201, "roughness": 0.0343, "metallic": 0.0629}


def read_ablation(*dirs: Path) -> dict | None:
    """The first ``fivelight.json`` found in ``dirs`` (None when none is)."""
    for d in dirs:
        f = Path(d) / ABLATION_FILE
        if f.is_file():
            return json.loads(f.read_text())
    return None


def models_section(ablation: dict | None) -> list[str]:
    """The "Five known lights" section of ``models.md``: the loss ablation beside the paper's
    figures (from ``fivelight.json``; None: a pointer to ``ebr bench fivelight`` only)."""
    lines = ["## Five known lights", ""]
    link = (
        "The five-light dual-loss model, its estimate path and the comparison with this page's flash / "
        "no-flash model on the same materials: [fivelight.md](fivelight.md) (`ebr bench fivelight`)."
    )
    if not ablation or not ablation.get("runs"):
        return lines + [
            link,
            "",
            "(The ablation's table appears here once `ebr bench fivelight` has written "
            f"`{ABLATION_FILE}` beside this page; until then [fivelight.md](fivelight.md) has the last "
            "one measured.)",
            "",
        ]
    verdict = ablation_lines(ablation["runs"], list(ablation["runs"]))
    return lines + [
        link,
        "",
        f"The paper's loss ablation, measured by `ebr bench fivelight` on {ablation['date']} "
        f"({ablation['machine']}) on the {ablation['n']} five-light captures of this test split's "
        "materials (no environment, 256², Mitsuba): the same U-Net, data and steps "
        "(`configs/dualloss_real*.toml`), trained with the dual loss, the parameter loss only and the "
        "rendering loss only. Per-map RMSE as above; base colour / metallic are both maps read as glTF "
        "metal/rough (`ebr_mitsuba.metrics.metal_rough_rmse`), the paper's map convention; the re-render "
        "is under 30 seeded point lights and views none of the five lights the models saw."
        + (" **Quick run, not the documented figures.**" if ablation.get("quick") else ""),
        "",
        *ablation_table(ablation),
        *verdict,
        "The paper's row is for orientation only: **its test set differs** (29 hand-picked real materials "
        "photographed, 512², base colour / metallic maps) and its network is paper-size, trained on a "
        "GPU on 815 texture sets; ours is small, trained on two CPU cores on this toolkit's real and "
        "procedural sets.",
        "",
    ]


def ablation_table(ablation: dict) -> list[str]:
    """The ablation runs' figures and the paper's row, one table."""
    cols = ("normal", "diffuse", "roughness", "specular", "mean")
    head = (
        "| loss (Boss et al. 2018 ablation) | normal | diffuse | roughness | specular | mean | base colour "
        "| metallic | held-out re-render | training |"
    )
    rule = "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
    rows = []
    for name, r in ablation["runs"].items():
        pm, mr = r["per_map_rmse"], r["metal_rough"]
        cells = " | ".join(f"{pm[k]:.4f}" for k in cols)
        rows.append(
            f"| {name} | {cells} | {mr['base colour']:.4f} | {mr['metallic']:.4f} | "
            f"{r['rerender_rmse']:.4f} | {r['steps']} steps, {r['hours']:.2f} h |"
        )
    rows.append(
        f"| paper, dual loss (their test set) | {PAPER['normal']:.4f} | | {PAPER['roughness']:.4f} | | | "
        f"{PAPER['base colour']:.4f} | {PAPER['metallic']:.4f} | | GPU, 815 texture sets |"
    )
    return [head, rule, *rows, ""]


def ablation_lines(results: dict, names: list[str]) -> list[str]:
    if len(names) < 3 or not names[0].startswith("dual"):
        return ["(The ablation needs three runs in EBR_FIVELIGHT_RUNS, the dual loss first.)", ""]
    dual, others = results[names[0]], [results[k] for k in names[1:]]
    lines = []
    for key, label in (("mean", "mean per-map RMSE"), (None, "held-out-light re-render RMSE")):
        d = dual["per_map_rmse"][key] if key else dual["rerender_rmse"]
        vals = [o["per_map_rmse"][key] if key else o["rerender_rmse"] for o in others]
        wins = all(d < v for v in vals)
        parts = ", ".join(f"{nm} {v:.4f} ({(d - v) / v:+.0%})" for nm, v in zip(names[1:], vals))
        lines.append(
            f"- **{label}**: dual {d:.4f} against {parts} — the dual loss "
            + ("beats both single losses." if wins else "does **not** beat both single losses.")
        )
    return lines + [""]


__all__ = ["ABLATION_FILE", "PAPER", "ablation_lines", "ablation_table", "models_section", "read_ablation"]
