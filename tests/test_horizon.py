"""Lobes at the horizon (``ebr_mitsuba/estimate/horizon.py``) and the SG irradiance they are
judged by: the irradiance against the numpy quadrature of :mod:`ebr_mitsuba.reference`; the drop
keeping the sample's irradiance exactly; ``ebr estimate --drop-horizon-lobes`` dropping and
recording them, the default keeping the network's lobes."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from ebr_mitsuba.colour import LUMINANCE
from ebr_mitsuba.estimate.horizon import HORIZON_Z, drop_horizon_lobes
from ebr_mitsuba.sgenv import SGEnvironment

# a lobe above the horizon, one straddling it (the horizon case), one below it, one at the zenith
AXES = np.array([[0.6, 0.0, 0.8], [0.0, np.sqrt(1 - 0.03**2), 0.03], [0.0, 0.6, -0.8], [0.0, 0.0, 1.0]])
SHARP = np.array([40.0, 12.0, 2.0, 1.5])
AMPS = np.array([[5.0, 4.0, 3.0], [9.0, 9.0, 9.0], [0.2, 0.25, 0.3], [0.3, 0.35, 0.5]])


def test_irradiance_matches_the_quadrature():
    """SGEnvironment.irradiance (closed-form azimuth, Gauss–Legendre polar) against the vMF-rule
    quadrature of the reference, for lobes above, straddling and below the horizon; tolerance 1e-4
    relative (the reference converges to ~1e-6 at its default nodes)."""
    from ebr_mitsuba.reference import sg_irradiance

    env = SGEnvironment(AXES, SHARP, AMPS)
    for normal in ((0.0, 0.0, 1.0), (0.6, 0.0, 0.8)):
        ref = sum(sg_irradiance(a, s, m, np.array(normal)) for a, s, m in zip(AXES, SHARP, AMPS))
        assert env.irradiance(normal) == pytest.approx(np.asarray(ref, np.float64).reshape(3), rel=1e-4)


def test_drop_keeps_the_sample_irradiance():
    env = SGEnvironment(AXES, SHARP, AMPS)
    out, record = drop_horizon_lobes(env)
    low = AXES[:, 2] < HORIZON_Z
    assert record["applied"] is True and record["dropped"] == int(low.sum()) == 2
    assert out.num_lobes == 2
    np.testing.assert_allclose(out.axis, env.axis[~low], rtol=0, atol=1e-7)
    np.testing.assert_allclose(out.sharpness, env.sharpness[~low], rtol=1e-7)
    # what the photos measured stays: the irradiance on the sample plane, per channel
    np.testing.assert_allclose(out.irradiance(), env.irradiance(), rtol=1e-5)
    # the kept lobes keep their colour ratios, scaled by one gain per channel
    gain = np.asarray(record["gain"])
    np.testing.assert_allclose(out.amplitude, env.amplitude[~low] * gain[None, :], rtol=1e-5)
    assert np.all(gain > 1.0)
    # the dropped lobes' share of the irradiance, luminance, as recorded
    kept = SGEnvironment(env.axis[~low], env.sharpness[~low], env.amplitude[~low])
    share = 1.0 - (kept.irradiance() @ LUMINANCE) / (env.irradiance() @ LUMINANCE)
    assert record["irradiance_share"] == pytest.approx(share, rel=1e-6)
    # and an object standing on the sample sees less light from the side
    assert out.irradiance((1.0, 0.0, 0.0)) @ LUMINANCE < env.irradiance((1.0, 0.0, 0.0)) @ LUMINANCE
    assert out.irradiance((0.0, 1.0, 0.0)) @ LUMINANCE < env.irradiance((0.0, 1.0, 0.0)) @ LUMINANCE


@pytest.mark.parametrize("rows", [[0, 3], [1, 2]], ids=["none at the horizon", "all at the horizon"])
def test_nothing_to_drop_leaves_the_environment(rows):
    env = SGEnvironment(AXES[rows], SHARP[rows], AMPS[rows])
    out, record = drop_horizon_lobes(env)
    assert out is env and record == {"applied": False, "dropped": 0, "min_z": HORIZON_Z}


def test_estimate_drops_horizon_lobes_when_told(tmp_path, capsys, monkeypatch):
    """The network's environment with a lobe at the horizon: ebr estimate's env.json keeps it by
    default (estimate.json records null); with --drop-horizon-lobes it is dropped (recorded, the
    sample's irradiance unchanged)."""
    from fakes import FakePredictor, write_pair

    from ebr_mitsuba.cli import main
    from ebr_mitsuba.estimate import pipeline

    network_env = SGEnvironment(AXES[[0, 1, 3]], SHARP[[0, 1, 3]], AMPS[[0, 1, 3]])

    class HorizonPredictor(FakePredictor):
        def predict(self, flash, noflash, far_flash=None, far_noflash=None):
            return replace(super().predict(flash, noflash, far_flash, far_noflash), env=network_env)

    monkeypatch.setattr(pipeline, "load_predictor", lambda checkpoint: HorizonPredictor())
    (tmp_path / "cap").mkdir()
    cap = write_pair(tmp_path / "cap", seed=1)
    shots = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr", "--no-flash-fit"]
    envs = {}
    for name, extra in (("dropped", ["--drop-horizon-lobes"]), ("kept", [])):
        code = main(["estimate", *map(str, shots), "--out", str(tmp_path / name), "--json", *extra])
        out = capsys.readouterr()
        assert code == 0, out.err
        summary = json.loads(out.out)
        envs[name] = SGEnvironment.load(tmp_path / name / "env.json")
        if name == "dropped":
            assert summary["horizon_lobes"]["applied"] is True and summary["horizon_lobes"]["dropped"] == 1
            assert summary["lobes"] == 2
        else:
            assert summary["horizon_lobes"] is None and summary["lobes"] == 3
    assert envs["kept"].num_lobes == 3 and envs["dropped"].num_lobes == 2
    assert np.all(envs["dropped"].axis[:, 2] >= HORIZON_Z)
    np.testing.assert_allclose(envs["dropped"].irradiance(), envs["kept"].irradiance(), rtol=1e-4)
