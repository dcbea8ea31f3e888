"""``ebr dataset sheet``: a contact sheet of a generated data set (matplotlib, PNG).

One row per sample (``samples`` of them, evenly spaced over the index, 16 by default); columns:
the four maps (normal as (n+1)/2, diffuse and specular sRGB-encoded, roughness grey), every photo
of the first two shots (sRGB as stored), the first flash-only image, the environment exemplars and
the point-light exemplars. HDR images (flash-only, exemplars; stored in the photos' camera units)
are shown as the camera would record them, clipped to [0, 1] and sRGB-encoded, like the photos.
Row labels give the index, the material and the environment.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..imageio import linear_to_srgb
from . import store


def _display(image: np.ndarray, kind: str) -> np.ndarray:
    if kind == "normal":
        return np.clip((image + 1.0) * 0.5, 0.0, 1.0)
    if kind == "grey":
        return np.clip(image, 0.0, 1.0)
    return linear_to_srgb(np.clip(image, 0.0, 1.0))


def _columns(dataset: dict, max_photos: int = 2) -> list[tuple[str, str, object]]:
    lay = dataset["layout"]
    cols = [
        ("normal", "normal", ("maps", "normal")),
        ("diffuse", "srgb", ("maps", "diffuse")),
        ("specular", "srgb", ("maps", "specular")),
        ("roughness", "grey", ("maps", "roughness")),
    ]
    cols += [(name, "srgb", ("photos", name)) for name in list(lay["photos"])[:max_photos]]
    cols += [(f"{name} (flash only)", "srgb", ("flash_only", name)) for name in list(lay["flash_only"])[:1]]
    env_r = dataset["config"]["exemplars"]["env_roughness"]
    point_r = dataset["config"]["exemplars"]["point_roughness"]
    cols += [(f"env r={r:g}", "srgb", ("env_exemplars", i)) for i, r in enumerate(env_r)]
    cols += [(f"point r={r:g}", "srgb", ("point_exemplars", i)) for i, r in enumerate(point_r)]
    return cols


def contact_sheet(
    root: str | Path, out: str | Path, samples: int = 16, thumb_inches: float = 0.9, dpi: int = 110
) -> Path:
    """Draw the contact sheet of the data set at ``root`` into ``out`` (PNG, ``dpi`` dots per inch,
    thumbnails ``thumb_inches`` wide); returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..fsutil import atomic_path

    root = Path(root)
    for name in (store.DATASET_JSON, store.INDEX_JSON):
        if not (root / name).is_file():
            raise InputError(f"{root / name}: missing; give a complete data set (ebr generate)")
    if samples < 1:
        raise InputError(f"--samples must be >= 1 (got {samples})")
    dataset = store.read_json(root / store.DATASET_JSON)
    index = store.read_json(root / store.INDEX_JSON)
    count = int(index["count"])
    picks = sorted(set(np.linspace(0, count - 1, min(samples, count)).round().astype(int).tolist()))
    cols = _columns(dataset)
    fig, axes = plt.subplots(
        len(picks),
        len(cols),
        squeeze=False,
        figsize=(thumb_inches * len(cols) + 1.6, thumb_inches * len(picks) + 0.4),
    )
    for r, i in enumerate(picks):
        s = store.load_sample(root, dataset, i)
        entry = index["samples"][i]
        for c, (title, kind, (group, key)) in enumerate(cols):
            ax = axes[r, c]
            image = s[group][key]
            shown = _display(image, kind)
            ax.imshow(
                shown, cmap="gray" if shown.ndim == 2 else None, vmin=0.0, vmax=1.0, interpolation="nearest"
            )
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(title, fontsize=6)
        material = Path(str(entry["material"])).name.replace("procedural:", "")
        label = f"{i}\n{material[:18]}\n{Path(str(entry['env'])).name[:18]}"
        axes[r, 0].set_ylabel(label, fontsize=5, rotation=0, ha="right", va="center")
    fig.subplots_adjust(left=0.1, right=0.995, top=0.97, bottom=0.005, wspace=0.03, hspace=0.05)
    out = Path(out)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return out
