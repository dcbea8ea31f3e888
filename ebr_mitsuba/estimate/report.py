"""``report.html``: one self-contained page (every picture embedded as a base64 PNG) per estimate.

Sections: summary and input checks (warnings), the inputs, the maps (and the network's maps
before refinement), how the flash-profile fit read them, the lighting (hemisphere and lat-long
pictures of the SGs, exemplars; for a multi-view estimate the per-pixel SGs and the views'
in-frame weights), the re-renders beside the photos and the residuals with their errors, the
refinement (errors before and after, loss curve), renders under novel lights, the per-map errors
against ground truth when known (``ebr demo``), and the time per stage. It reads the PNGs the
pipeline wrote into the output directory and the summary dict (``estimate.json``).
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from ..fsutil import atomic_write_text
from ..svbrdf import MAP_NAMES
from .inputs import HIGHLIGHT_MIN_R2

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;max-width:1400px;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.6em}
figure{display:inline-block;margin:0 .6em .8em 0;vertical-align:top;text-align:center}
figure img{width:220px;image-rendering:pixelated;border:1px solid #ddd}
figure.wide img{width:440px}figcaption{font-size:.85em;color:#444;max-width:440px}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.2em .6em;text-align:right}
th{background:#f3f3f3}td.l,th.l{text-align:left}.warn{color:#a40}.ok{color:#070}
"""


THUMBNAIL_SIZE = 512  # pictures larger than this (per side) are embedded as thumbnails


def _png_bytes(path: Path) -> bytes:
    """The PNG's bytes, or a thumbnail of at most :data:`THUMBNAIL_SIZE` pixels per side (box
    filter on the stored codes) for larger ones (the maps of a 2048² estimate)."""
    from PIL import Image

    with Image.open(path) as im:
        if max(im.size) <= THUMBNAIL_SIZE:
            return path.read_bytes()
        im.thumbnail((THUMBNAIL_SIZE, THUMBNAIL_SIZE), Image.Resampling.BOX)
        import io

        buf = io.BytesIO()
        im.save(buf, format="PNG", compress_level=1)  # fast: the page is read once
        return buf.getvalue()


def _img(out: Path, rel: str, caption: str, wide: bool = False) -> str:
    path = out / rel
    if not path.is_file():
        return ""
    data = base64.b64encode(_png_bytes(path)).decode("ascii")
    cls = ' class="wide"' if wide else ""
    return (
        f'<figure{cls}><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def _fmt(v, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def _table(header: list[str], rows: list[list], left: int = 1) -> str:
    th = "".join(f"<th{' class=l' if i < left else ''}>{html.escape(h)}</th>" for i, h in enumerate(header))
    body = "".join(
        "<tr>"
        + "".join(f"<td{' class=l' if i < left else ''}>{_fmt(c)}</td>" for i, c in enumerate(r))
        + "</tr>"
        for r in rows
    )
    return f"<table><tr>{th}</tr>{body}</table>"


EXEMPLAR_KEY = 0.18  # thumbnails: the exemplar stack's mean luminance is shown as middle grey


def exemplar_exposure(images) -> float:
    """One exposure for a set of exemplar thumbnails: their mean luminance → :data:`EXEMPLAR_KEY`.

    Shared, so the set compares (the exemplars render one material at several roughness values
    under one light), and set on the mean rather than on a high percentile: exemplars are low in
    contrast, and mapping their 99.5th percentile to white left them washed out. 1 for black.
    """
    import numpy as np

    from .inputs import luminance

    lum = [luminance(np.asarray(a, np.float32)).astype(np.float64) for a in images]
    mean = float(np.mean([m.mean() for m in lum])) if lum else 0.0
    return EXEMPLAR_KEY / mean if mean > 0 and np.isfinite(mean) else 1.0


_SVG_PAD = (46, 10, 16, 12)  # left (tick labels), right, top, bottom


def _loss_svg(history: list, width: int = 420, height: int = 140) -> str:
    """A small polyline of the refinement loss (log scale) over the steps.

    The first and last values are written beside their own points (not in fixed corners, where a
    label could sit next to a peak it does not describe); the left axis carries the maximum and
    minimum, so a peak is read off there.
    """
    import math

    pts = [(s, v) for s, v in history if v > 0 and math.isfinite(v)]
    if len(pts) < 2:
        return ""
    left, right, top, bottom = _SVG_PAD
    s0, s1 = pts[0][0], pts[-1][0]
    lv = [math.log10(v) for _, v in pts]
    lo, hi = min(lv), max(lv)
    span = (hi - lo) or 1.0

    def x(s):
        return left + (width - left - right) * (s - s0) / max(s1 - s0, 1)

    def y(level):
        return top + (height - top - bottom) * (hi - level) / span

    xy = " ".join(f"{x(s):.1f},{y(level):.1f}" for (s, _), level in zip(pts, lv))

    def beside(px, py, anchor, text):  # above the point, or below it when at the top edge
        ty = py - 6 if py - 6 >= top + 4 else py + 14
        return (
            f'<text x="{px:.1f}" y="{ty:.1f}" font-size="11" text-anchor="{anchor}">'
            f"{html.escape(text)}</text>"
        )

    def tick(level, value):
        return (
            f'<text x="{left - 4}" y="{y(level) + 4:.1f}" font-size="10" text-anchor="end" '
            f'fill="#666">{value:.3g}</text>'
        )

    return (
        f'<svg width="{width}" height="{height}" style="border:1px solid #ddd">'
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{height - bottom}" stroke="#aaa"/>'
        + tick(hi, max(v for _, v in pts))
        + tick(lo, min(v for _, v in pts))
        + f'<polyline fill="none" stroke="#36c" stroke-width="2" points="{xy}"/>'
        + beside(x(s0) + 2, y(lv[0]), "start", f"loss {pts[0][1]:.3g} (step {s0})")
        + beside(x(s1) - 2, y(lv[-1]), "end", f"{pts[-1][1]:.3g} (step {s1})")
        + "</svg>"
    )


def flash_fit_rows(fit: dict) -> list[list]:
    """The flash-profile fit's record (``estimate.json``'s ``flash_fit``) as (what, value) rows in
    words: what the roughness, specular and albedo level were read as, and how sure the
    metal-or-dielectric decision was (docs/estimate.md, "The flash-profile fit")."""
    from .flashfit import METAL_MARGIN, METAL_MAX_ROUGHNESS, FlashFitConfig

    defaults = FlashFitConfig()
    kind = "metal (no diffuse part)"
    if not fit.get("metal"):
        kind = f"dielectric (F0 {_fmt(defaults.f0)} and a diffuse part)"
    rows = [["material read as", kind]]
    decision = fit.get("decision")
    if decision:
        ratio, rough = decision.get("metal_ratio"), decision.get("metal_roughness")
        text = f"best metal's ring cost ÷ best dielectric's: {_fmt(ratio, 3)} (a metal needs below "
        text += f"{_fmt(METAL_MARGIN)} and a lobe sharper than roughness {_fmt(METAL_MAX_ROUGHNESS)}; "
        text += f"its roughness {_fmt(rough, 3)})"
        rows.append(["metal or dielectric", text])
    source = fit.get("roughness_from", "fit")
    how = "the flash profile"
    if source == "network":
        residual, limit = _fmt(fit.get("misfit"), 3), _fmt(defaults.misfit_limit)
        how = f"the network's map: the profile misfits (ring residual {residual} > {limit})"
    elif fit.get("far_pair"):
        how = "near − far rings (the far pair)"
    elif fit.get("relief"):
        how = "the sharp lobe of a two-lobe profile (relief read as the broad one)"
    elif (fit.get("pixel_median") or {}).get("used"):
        pm = fit["pixel_median"]
        how = (
            f"mean of the profile's {_fmt(pm['profile'], 3)} and the pixel-median reading's "
            f"{_fmt(pm['roughness'], 3)}"
        )
    rows.append(["roughness", f"{_fmt(fit.get('roughness'), 3)}, from {how}"])
    pattern = fit.get("roughness_pattern")
    if pattern and source != "network":
        if pattern.get("applied"):
            text = (
                f"{_fmt(pattern['slope'], 3)} roughness per unit of log-albedo around it (read "
                f"{_fmt(pattern.get('read'), 3)} ± {_fmt(pattern.get('stderr'), 2)} off the flash "
                "highlight; --no-roughness-pattern keeps the constant)"
            )
        else:
            text = f"not read ({pattern.get('reason', '')}): the map is the constant"
        rows.append(["roughness pattern", text])
    rows.append(["specular F0 (RGB)", ", ".join(_fmt(x, 3) for x in fit.get("specular", []))])
    rows.append(["albedo level (RGB)", ", ".join(_fmt(x, 3) for x in fit.get("diffuse_level", []))])
    return rows


def _flash_fit_section(fit: dict | None, shading: dict | None, tilt: dict | None = None) -> str:
    if not fit:
        return ""
    rows = flash_fit_rows(fit)
    if tilt is not None:  # a metal or a glossy sample: the network's normals or the highlight's tilt
        why = "a metal" if fit.get("metal") else "a glossy sample: glints would mislead the shading fit"
        if tilt.get("applied"):
            slope = ", ".join(_fmt(x, 4) for x in tilt["slope"])
            normals = (
                f"flat, tilted {_fmt(tilt['degrees'], 2)}° to the flash shot's clipped highlight "
                f"(slopes {slope}; {why}; --no-highlight-tilt keeps the network's)"
            )
        else:
            normals = f"the network's ({why}; highlight tilt not used: {tilt.get('reason', 'off')})"
        rows.append(["normals", normals])
    elif shading is not None:
        normals = "the network's (a glossy sample: glints would mislead the shading fit)"
        if shading.get("applied"):
            normals = "shading normals: the albedo texture scaled by the flash / no-flash shading"
            if shading.get("map_gain") is not None:
                normals += f" (× {_fmt(shading['map_gain'], 2)} in the map, --normal-gain)"
            relief = shading.get("relief")
            if relief and shading.get("relief_gain"):
                sky = ", ".join(_fmt(x, 2) for x in relief["sky_gradient"])
                normals += (
                    f", plus the relief the albedo does not show, read off the rest of that ratio "
                    f"(slopes rms {_fmt(relief['slope_rms'], 3)}, × {_fmt(shading['relief_gain'], 2)} "
                    f"in the map, --relief-gain; sky gradient {sky})"
                )
        rows.append(["normals", normals])
    return (
        "<h2>How the maps were read</h2><p>The flash-profile fit after the network (estimate.json "
        "<code>flash_fit</code>; <code>--no-flash-fit</code> keeps the network's maps).</p>"
        + _table(["", "value"], rows, left=2)
    )


def render_report(out: Path, summary: dict) -> str:
    """The HTML text of the report for the estimate directory ``out`` (its PNGs must exist)."""
    out = Path(out)
    inp = summary["inputs"]
    # ``out`` is the pipeline's temporary directory; the title names the final one
    name = Path(summary.get("out") or out).name
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>ebr estimate: {html.escape(name)}"
        f"</title><style>{_CSS}</style></head><body>",
        f"<h1>ebr estimate — {html.escape(summary['capture'])} capture</h1>",
    ]
    if "views" in inp:  # multi-view: each view with its camera
        shot_rows = [
            [f"{k} (camera at {', '.join(f'{c:g}' for c in inp['views'][k]['camera'])})", p]
            for k, p in inp["paths"].items()
        ]
    elif "lights" in inp:  # five-light: each photo with its light's position
        shot_rows = [
            [f"{k} (light at {', '.join(f'{c:g}' for c in inp['lights'][k])})", p]
            for k, p in inp["paths"].items()
        ]
    else:
        shot_rows = [
            ["flash shot", inp["paths"].get("flash")],
            ["no-flash shot", inp["paths"].get("noflash", "— (flash-only: no lighting estimate)")],
            *(
                [["far shots", f"{inp['paths']['far_flash']}, {inp['paths']['far_noflash']}"]]
                if "far_flash" in inp["paths"]
                else []
            ),
        ]
    parts.append(
        _table(
            ["item", "value"],
            [
                *shot_rows,
                ["input size", "x".join(str(v) for v in inp["source_size"][::-1])],
                [
                    "working resolution",
                    f"{summary['resolution']}² (model grid {summary['model_grid']}², "
                    + (
                        "one pass"
                        if summary.get("tiles", 1) == 1
                        else f"{summary['tiles']} tiles of {summary['tile']}²"
                    )
                    + ")",
                ],
                ["field of view", f"{inp['fov']:g}°"],
                [
                    "light intensity" if "lights" in inp else "flash intensity",
                    "; ".join(
                        f"{k}: {v['intensity']:.4g} W/sr ({v['source']})" for k, v in summary["flash"].items()
                    ),
                ],
                *(
                    [
                        ["SG lobes per pixel", summary["lobes"]],
                        [
                            "renderer",
                            "torch BRDF (nets/mair_render.py): each view's flash + the per-pixel SGs "
                            "(lighting scale "
                            + " / ".join(f"{x:.4g}" for x in summary["lighting"]["scale"])  # R / G / B
                            + ", fitted)",
                        ],
                    ]
                    if "views" in inp
                    else [
                        ["SG lobes", summary["lobes"]],
                        ["renderer", f"fast Dr.Jit renderer, environment term '{summary['render_mode']}'"],
                    ]
                    if "lights" not in inp
                    else [["renderer", "fast Dr.Jit renderer, the point lights alone"]]
                ),
                ["total time", f"{summary.get('total_seconds', sum(summary['timings'].values())):.1f} s"],
            ],
        )
    )

    parts.append("<h2>Input checks</h2>")
    rows = [[k, f"×{v['factor']:.4g}", v["source"]] for k, v in inp["exposure"].items()]
    parts.append(_table(["shot", "exposure factor", "source"], rows))
    checks = [["saturated pixels", f"{inp['saturated_fraction']:.2%}"]]
    for k, (dy, dx) in inp["shifts"].items():
        checks.append([f"alignment ({k} pair)", f"dx {dx:+.1f}, dy {dy:+.1f} px"])
    hl = inp["highlight"] or {"position": None, "fit_r2": 0.0}
    pos, r2 = hl["position"], hl["fit_r2"]
    if inp["highlight"] is None and "views" in inp:
        verdict = "not checked (a multi-view capture: nine flashes at known positions)"
    elif inp["highlight"] is None:
        verdict = "not checked (no light at the camera)"
    elif r2 < HIGHLIGHT_MIN_R2:
        verdict = f"not measurable: the texture dominates the flash falloff (fit R² {r2:.2f})"
    elif pos is None:
        verdict = f"not found (fit R² {r2:.2f})"
    else:
        verdict = f"x {pos[0]:+.2f}, y {pos[1]:+.2f} half-widths from the centre (fit R² {r2:.2f})"
    checks.append(["flash highlight", verdict])
    parts.append(_table(["check", "result"], checks))
    if summary["warnings"]:
        parts.append(
            "<ul>" + "".join(f'<li class="warn">{html.escape(w)}</li>' for w in summary["warnings"]) + "</ul>"
        )
    else:
        parts.append('<p class="ok">All input checks passed.</p>')

    shots = list(summary["rerender_error"]["network"].keys())
    shots = [s for s in shots if s != "mean"]
    parts.append("<h2>Inputs</h2>" + "".join(_img(out, f"inputs/{s}.png", s) for s in shots))
    if "views" in inp:
        parts.append(
            "<p>The views rectified onto the sample grid (above) and their in-frame weights (white: "
            "the camera saw the point):</p>"
            + "".join(_img(out, f"weights/{s}.png", f"{s}: in frame") for s in shots)
        )

    parts.append("<h2>Maps</h2>")
    parts.append("".join(_img(out, f"maps/{m}.png", m) for m in MAP_NAMES))
    if summary.get("refine"):
        parts.append("<p>Network maps, before refinement:</p>")
        parts.append("".join(_img(out, f"maps_network/{m}.png", f"{m} (network)") for m in MAP_NAMES))

    parts.append(
        _flash_fit_section(
            summary.get("flash_fit"), summary.get("shading_normals"), summary.get("highlight_tilt")
        )
    )

    parts.append("<h2>Lighting</h2>")
    if summary["capture"] == "flash-only":
        parts.append("<p>Flash-only capture: no environment estimated.</p>")
    elif "views" in inp:
        env_json = summary.get("lighting", {}).get("env_json", "the centre pixel's lobes")
        parts.append(
            f"<p>{summary['lobes']} spherical Gaussians per pixel (lighting/lobes.exr, "
            "lighting/lighting.json): the incident lighting of 4 × 4 pixels (each hemisphere seen from "
            "above, +x right, +y up, laid out as in the image), the irradiance they give the plane, and "
            f"the environment for insertion (env.json: {html.escape(env_json)}).</p>"
            + _img(out, "lighting/hemispheres.png", "per-pixel lighting, 4 × 4 pixels", wide=True)
            + _img(out, "lighting/irradiance.png", "irradiance from the SGs")
            + _img(out, "env_sphere.png", "env.json: upper hemisphere seen from above")
            + _img(out, "env_latlong.png", "env.json: lat-long, z up", wide=True)
        )
    elif "lights" in inp:
        parts.append(
            f"<p>Five point lights at known positions ({html.escape(str(inp.get('geometry')))}), "
            "no environment: nothing to estimate.</p>"
        )
    else:
        parts.append(
            _img(out, "env_sphere.png", "upper hemisphere seen from above (+x right, +y up)")
            + _img(out, "env_latlong.png", "lat-long, z up (top row zenith)", wide=True)
        )
    ex = sorted(p.name for p in (out / "exemplars").glob("*.png")) if (out / "exemplars").is_dir() else []
    if ex:
        parts.append(
            "<p>Lighting network outputs (exemplars at one shared exposure, their mean luminance shown "
            "as middle grey; flash-only image):</p>"
            + "".join(_img(out, f"exemplars/{n}", n[:-4]) for n in ex)
        )

    parts.append(
        "<h2>Re-renders and residuals</h2><p>Photo, re-render of the estimate and residual "
        "(re-render − photo, luminance; blue darker, red brighter; full scale ±50% of the photo's "
        "RMS). Errors over unsaturated pixels, linear.</p>"
    )
    err_net, err_ref = summary["rerender_error"]["network"], summary["rerender_error"]["refined"]
    for s in shots:
        e = (err_ref or err_net)[s]
        photo = _img(out, f"inputs/{s}.png", f"{s}: photo")
        rend = _img(out, f"rerender/{s}.png", "re-render (RMSE {:.4g})".format(e["rmse"]))
        resid = _img(out, f"residual/{s}.png", "residual (relative RMSE {:.3f})".format(e["rel_rmse"]))
        before = (
            _img(out, f"rerender_network/{s}_residual.png", "residual before refinement") if err_ref else ""
        )
        parts.append(f"<div>{photo}{rend}{resid}{before}</div>")
    rows = [
        [
            s,
            err_net[s]["rmse"],
            err_net[s]["rel_rmse"],
            *([err_ref[s]["rmse"], err_ref[s]["rel_rmse"]] if err_ref else []),
        ]
        for s in shots + ["mean"]
    ]
    header = ["shot", "RMSE network", "rel. RMSE network"] + (
        ["RMSE refined", "rel. RMSE refined"] if err_ref else []
    )
    parts.append(_table(header, rows))

    if summary.get("refine"):
        r = summary["refine"]
        before, after = err_net["mean"]["rmse"], err_ref["mean"]["rmse"]
        change = (after - before) / before if before > 0 else float("nan")
        parts.append(
            f"<h2>Refinement</h2><p>{r['steps']} Adam steps ({'maps and lobes' if r['lobes'] else 'maps'}) "
            f"in {r['seconds']:.1f} s: mean re-render RMSE {before:.4g} → {after:.4g} "
            f"({change:+.1%}).</p>" + _loss_svg(r["history"])
        )
        if r.get("note"):  # issue 16 item 18: the loss rose, the best iterate was kept
            parts.append(f'<p class="warn">Refinement {html.escape(r["note"])}.</p>')
        if r.get("budget_note"):  # issue 12: the time budget stopped the refinement
            parts.append(f'<p class="warn">Refinement {html.escape(r["budget_note"])}.</p>')

    novel = sorted(p.name for p in (out / "novel").glob("*.png")) if (out / "novel").is_dir() else []
    if novel:
        parts.append(
            "<h2>Novel lighting</h2>"
            + "".join(_img(out, f"novel/{n}", n[:-4].replace("_", " ")) for n in novel)
        )

    if summary.get("map_error"):
        me = summary["map_error"]
        rows = [
            [m, me["network"][m], *([me["refined"][m]] if me["refined"] else [])]
            for m in (*MAP_NAMES, "mean")
        ]
        parts.append(
            "<h2>Against ground truth</h2><p>Per-map RMSE (normals as (n+1)/2).</p>"
            + _table(["map", "network"] + (["refined"] if me["refined"] else []), rows)
        )

    t = summary["timings"]
    parts.append("<h2>Time per stage</h2>" + _table(["stage", "seconds"], [[k, v] for k, v in t.items()]))
    pt = summary.get("prediction_timings") or {}
    if pt:
        parts.append(
            "<p>Inside the prediction:</p>" + _table(["step", "seconds"], [[k, v] for k, v in pt.items()])
        )
    parts.append(
        f"<p style='color:#888;font-size:.8em'>ebr-mitsuba {html.escape(str(summary.get('version')))}"
        f"</p></body></html>"
    )
    return "\n".join(parts)


def write_report(out: Path, summary: dict) -> Path:
    """Write ``out/report.html``; returns its path."""
    path = Path(out) / "report.html"
    atomic_write_text(path, render_report(out, summary))
    return path


__all__ = ["EXEMPLAR_KEY", "exemplar_exposure", "render_report", "write_report"]
