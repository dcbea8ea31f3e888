"""Checks shared by the tests of the benchmarks that read validation data sets from ``$VAR``
(``ebr bench flash-fit``, ``ebr bench normals``)."""

from __future__ import annotations

import pytest

from ebr_mitsuba.errors import InputError


def assert_needs_data_sets(bench, var: str, tmp_path, monkeypatch) -> None:
    """``bench.run`` refuses a path that is not a data set, and ``$var`` (and ``EBR_VAL_DATA``)
    unset: ``unavailable()`` and the error name ``$var``."""
    monkeypatch.setenv(var, str(tmp_path / "missing"))
    with pytest.raises(InputError, match="not a data set"):
        bench.run(tmp_path / "out", quick=True)
    monkeypatch.delenv(var)
    monkeypatch.delenv("EBR_VAL_DATA", raising=False)
    assert var in bench.unavailable()
    with pytest.raises(InputError, match=var):
        bench.run(tmp_path / "out", quick=True)
