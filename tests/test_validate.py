"""`ebr validate` and `ebr bench` (the command layer; the comparisons themselves are exercised here
at low spp, the documented numbers come from `ebr validate --markdown docs/validation.md`)."""

from __future__ import annotations

import json
import shutil

import pytest

from ebr_mitsuba.cli import main
from ebr_mitsuba.validate import bundled_cases_file, load_cases

GLOSSY = """
[[case]]
name = "glossy"
scene = "{scene}"
params = {{ diffuse = "0.2, 0.2, 0.2", specular = "0.5, 0.45, 0.4", roughness = "0.25", \
axis = "0 0 1, -0.5 0.1 0.86", sharpness = "2, 60", amplitude = "0.5 0.5 0.6, 8 7 6" }}
checks = [{checks}]
view_deg = 30
view_azimuth_deg = 0
points = 24
budgets = {{ {budgets} }}
"""


def _case_file(tmp_path, checks, budgets):
    scene = bundled_cases_file().parent / "validate_plane.xml"
    path = tmp_path / "cases.toml"
    path.write_text(GLOSSY.format(scene=scene, checks=checks, budgets=budgets))
    return path


def test_bundled_cases_parse_and_cover_every_check():
    cases = load_cases()
    assert len(cases) >= 10
    checks = {c for case in cases for c in case.checks}
    assert checks == {"fast-sg", "fast-quadrature", "builtin-bsdf", "builtin-emitter"}
    assert all(case.scene.is_file() for case in cases)


def test_quadrature_passes_and_biased_claim_fails(variant, tmp_path, capsys):
    """The quadrature mode holds a 2% budget on a glossy highlight; the closed form, held to 0%,
    is caught (its measured ~18% bias is far above 3·noise at 1024 spp)."""
    path = _case_file(tmp_path, '"fast-quadrature", "fast-sg"', "fast-sg = 0.0")
    md = tmp_path / "v.md"
    rc = main(["validate", str(path), "--spp", "1024", "--json", "--markdown", str(md)])
    out = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in out["cases"]}
    assert rows["glossy/fast-quadrature"]["passed"], rows["glossy/fast-quadrature"]
    assert not rows["glossy/fast-sg"]["passed"]
    assert rows["glossy/fast-sg"]["excess"] > 0.1
    assert rc == 1 and out["passed"] is False
    text = md.read_text()
    assert "glossy/fast-sg" in text and "**no**" in text


def test_builtin_bsdf_check_on_an_xml_scene(variant, tmp_path, capsys):
    """An XML argument runs every check; the plugin matches Mitsuba's built-ins within budget."""
    scene = tmp_path / "plane.xml"
    shutil.copy(bundled_cases_file().parent / "validate_plane.xml", scene)
    rc = main(["validate", str(scene), "--spp", "256", "--json"])
    out = json.loads(capsys.readouterr().out)
    names = [r["name"] for r in out["cases"]]
    assert names == [f"plane/{c}" for c in ("fast-sg", "fast-quadrature", "builtin-bsdf", "builtin-emitter")]
    rows = {r["name"]: r for r in out["cases"]}
    for check in ("builtin-bsdf", "builtin-emitter", "fast-quadrature"):
        assert rows[f"plane/{check}"]["passed"], rows[f"plane/{check}"]
    assert rc == (0 if out["passed"] else 1)


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["validate", "missing.toml"], "no such file"),
        (["validate", "--case", "no_such_case"], "no such case"),
        (["validate", "--spp", "0"], "--spp"),
    ],
)
def test_bad_input_is_one_line_exit_2(variant, argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


def test_malformed_and_unknown_keys_rejected(variant, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[case]\nname = 1")
    assert main(["validate", str(bad)]) == 2
    assert "malformed TOML" in capsys.readouterr().err
    bad.write_text('[[case]]\nname = "x"\nscene = "validate_plane.xml"\nspp = 3\n')
    assert main(["validate", str(bad)]) == 2
    assert "unknown key(s) ['spp']" in capsys.readouterr().err


def test_bench_lists_and_rejects(variant, capsys):
    from ebr_mitsuba.commands.bench import available

    assert "generate" in available()
    assert main(["bench", "nonsense"]) == 2
    missing = [b for b in ("renderer", "generate", "extract-sg", "estimate") if b not in available()]
    if missing:
        assert main(["bench", missing[0]]) == 2
        assert "not in this version" in capsys.readouterr().err
