"""Every XML example in the documentation loads (issue 16, item 9).

The examples are the fenced ``xml`` blocks (```` ```xml ```` or ``~~~xml``) of ``docs/*.md`` and of
the plugin class docstrings (from which ``docs/plugins.md`` is generated). Each block holds one
element; it is loaded with ``mi.load_string`` (a ``version`` attribute added when absent), with
small generated files for the ``filename`` values it names (found through Mitsuba's file
resolver). XML outside such a block would escape the test, so that is refused too.
"""

from __future__ import annotations

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from ebr_mitsuba.sgenv import SGEnvironment

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PLUGIN_CLASSES = {"sgenvmap": "SGEnvMap", "svbrdf": "SVBRDFBSDF"}
_FENCE = re.compile(r"^[ \t]*(```|~~~)xml[ \t]*\n(.*?)^[ \t]*\1[ \t]*$", re.M | re.S)
_TAG = re.compile(r"<(scene|emitter|bsdf|shape|texture|sensor|integrator|film|sampler|bitmap)\b")
_KINDS = {
    "emitter": "Emitter",
    "bsdf": "BSDF",
    "texture": "Texture",
    "shape": "Shape",
    "sensor": "Sensor",
    "integrator": "Integrator",
    "scene": "Scene",
}


def _plugin_docstrings() -> dict[str, str]:
    """Class docstrings read from the plugin sources (collection runs before a variant is set, so
    the variant-specific classes cannot be imported here)."""
    out = {}
    for module, cls in PLUGIN_CLASSES.items():
        tree = ast.parse((ROOT / "plugins" / f"{module}.py").read_text(encoding="utf-8"))
        node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
        out[f"{module} docstring"] = ast.get_docstring(node)
    return out


def _sources() -> dict[str, str]:
    out = {f"docs/{p.name}": p.read_text(encoding="utf-8") for p in sorted(DOCS.glob("*.md"))}
    out.update(_plugin_docstrings())
    return out


def _examples() -> list[tuple[str, str]]:
    out = []
    for where, text in _sources().items():
        for i, match in enumerate(_FENCE.finditer(text)):
            out.append((f"{where} #{i + 1}", match.group(2)))
    return out


EXAMPLES = _examples()


def test_docs_have_xml_examples_and_none_outside_fences():
    where = {w.rsplit(" #", 1)[0] for w, _ in EXAMPLES}
    assert {"docs/plugins.md", "sgenvmap docstring", "svbrdf docstring"} <= where
    for name, text in _sources().items():
        rest = _FENCE.sub("", text)
        stray = _TAG.search(rest)
        assert stray is None, f"{name}: XML outside an xml block: {rest[stray.start() :][:60]!r}"


def _write_asset(path: Path) -> None:
    """A small stand-in for the file an example names (by extension)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        SGEnvironment(
            [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], [2.0, 300.0], [[0.5, 0.5, 0.6], [20.0, 18.0, 15.0]]
        ).save(path)
    elif path.suffix in (".exr", ".png"):
        value = (0.0, 0.0, 1.0) if "normal" in path.stem else (0.5, 0.4, 0.3)
        image = np.broadcast_to(np.asarray(value, np.float32), (4, 4, 3)).copy()
        if path.suffix == ".png":
            image = (np.clip(image, 0, 1) * 255).astype(np.uint8)
        mi.Bitmap(image).write(str(path))
    else:
        raise AssertionError(f"no stand-in for {path.name}: teach _write_asset its format")


def _filenames(root: ET.Element) -> list[str]:
    names = [e.get("filename") for e in root.iter() if e.get("filename")]
    names += [e.get("value") for e in root.iter("string") if e.get("name") == "filename"]
    return names


@pytest.fixture
def resolver_dir(tmp_path):
    """``tmp_path`` first on Mitsuba's file resolver for the test, the resolver restored after."""
    fr = mi.file_resolver()
    saved = [str(p) for p in fr]
    fr.prepend(str(tmp_path))
    yield tmp_path
    fr.clear()
    for p in saved:
        fr.append(p)


@pytest.mark.parametrize("where, xml", EXAMPLES, ids=[w for w, _ in EXAMPLES])
def test_xml_example_loads(where, xml, resolver_dir):
    root = ET.fromstring(xml)  # one well-formed element per block
    for name in _filenames(root):
        _write_asset(resolver_dir / name)
    if "version" not in root.attrib:
        xml = re.sub(rf"<{root.tag}\b", f'<{root.tag} version="3.0.0"', xml.strip(), count=1)
    obj = mi.load_string(xml)
    assert root.tag in _KINDS, f"{where}: unexpected root <{root.tag}>"
    kind = getattr(mi, _KINDS[root.tag])
    assert isinstance(obj, kind), f"{where}: loaded {type(obj).__name__}, not a {kind.__name__}"
    if root.tag == "bsdf":  # the textures are read: a frontal evaluation is finite and positive
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(0.0, 0.0, 1.0)
        si.uv = mi.Point2f(0.5, 0.5)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        value = np.asarray(obj.eval(mi.BSDFContext(), si, mi.Vector3f(0.0, 0.6, 0.8)), np.float64)
        assert np.all(np.isfinite(value)) and value.min() > 0, f"{where}: BSDF value {value}"
