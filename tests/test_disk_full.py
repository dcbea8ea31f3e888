"""A full disk is bad input, not an internal error (issue 16, item 6).

Every writer that hits ENOSPC — an EXR (OpenEXR), a JSON file (``pathlib`` under
``fsutil.atomic_write_text``), the estimate output directory, a data-set sample of ``ebr generate``
— makes the command exit 2 with one line ``no space left on device DEVICE writing PATH; free space
on DEVICE or choose another --out``, PATH being the file's final name (not its temporary one), and
leaves nothing half-written. The default suite injects the error (monkeypatched writers);
``test_real_tmpfs`` (root only) fills a real 64 KiB tmpfs.
"""

from __future__ import annotations

import errno
import os
import pathlib
import subprocess
from pathlib import Path

import pytest

from ebr_mitsuba.cli import disk_full_error, final_path, main
from ebr_mitsuba.errors import DiskFullError, is_disk_full, mount_point
from ebr_mitsuba.fsutil import atomic_dir, atomic_path

ENOSPC_TEXT = "No space left on device"


def _leftovers(directory: Path) -> list[str]:
    """Temporaries (and anything else) under ``directory``: what a failed writer left."""
    return sorted(p.relative_to(directory).as_posix() for p in directory.rglob("*"))


def _one_line(err: str, command: str) -> str:
    """The one error line (progress lines may precede it)."""
    lines = [line for line in err.strip().splitlines() if "error" in line]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"ebr {command}: error: no space left on device "), err
    assert err.strip().endswith(lines[0])
    assert "Traceback" not in err and "internal error" not in err
    return lines[0]


@pytest.fixture
def full_exr(monkeypatch):
    """OpenEXR's writer half-writes the file, then fails as it does on a full disk."""
    import OpenEXR

    real = OpenEXR.File

    class FullFile:
        def __init__(self, *args, **kwargs):
            self._file = real(*args, **kwargs)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, path):
            Path(path).write_bytes(b"\x76\x2f\x31\x01 half")
            raise RuntimeError(f'Failed to write pixel data to image file "{path}". {ENOSPC_TEXT}.')

        def __getattr__(self, name):
            return getattr(self._file, name)

    monkeypatch.setattr(
        OpenEXR, "File", lambda *a, **k: FullFile(*a, **k) if a and isinstance(a[0], dict) else real(*a, **k)
    )


@pytest.fixture
def full_json(monkeypatch):
    """``Path.write_text`` of a ``.json`` file writes half, then raises ENOSPC without a file name
    (as ``write()`` does)."""
    real = pathlib.Path.write_text

    def write_text(self, data, *args, **kwargs):
        if ".json" in self.name:
            real(self, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, data, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "write_text", write_text)


# -- the pieces -------------------------------------------------------------------------------------


def test_disk_full_detection():
    assert is_disk_full(OSError(errno.ENOSPC, "x"))
    assert is_disk_full(OSError(errno.EDQUOT, "x"))
    assert is_disk_full(RuntimeError(f'Failed to write "a.exr". {ENOSPC_TEXT}.'))
    assert not is_disk_full(OSError(errno.EACCES, "Permission denied"))
    assert not is_disk_full(ValueError(ENOSPC_TEXT))


def test_final_path_undoes_fsutil_temporaries(tmp_path):
    with atomic_dir(tmp_path / "est") as d, atomic_path(d / "maps" / "normal.exr") as f:
        assert final_path(f) == str(tmp_path / "est" / "maps" / "normal.exr")
        assert final_path(d) == str(tmp_path / "est")
    with atomic_path(tmp_path / "r0.100.exr") as f, atomic_path(tmp_path / "noext") as g:
        assert final_path(f) == str(tmp_path / "r0.100.exr")
        assert final_path(g) == str(tmp_path / "noext")
    assert final_path("a/b.json") == str(Path("a/b.json"))


def test_disk_full_error_message_and_pickling(tmp_path):
    import pickle

    e = DiskFullError(tmp_path / "x.json")
    assert str(e) == (
        f"no space left on device {mount_point(tmp_path)} writing {tmp_path / 'x.json'}; "
        f"free space on {mount_point(tmp_path)} or choose another --out"
    )
    assert e.exit_code == 2
    again = pickle.loads(pickle.dumps(e))
    assert str(again) == str(e) and again.path == e.path


def test_disk_full_found_through_the_cause_chain(tmp_path):
    try:
        try:
            tmp = tmp_path / ".x.abcd1234.json.tmp.json"
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))
        except OSError as inner:
            raise RuntimeError("sample 3 failed") from inner
    except RuntimeError as outer:
        err = disk_full_error(outer)
    assert err is not None and err.path == str(tmp_path / "x.json")
    assert disk_full_error(RuntimeError("unrelated")) is None


# -- the commands -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def exemplar_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ex") / "exemplars"
    assert (
        main(
            [
                "exemplars",
                "--env",
                "procedural:3",
                "--renderer",
                "fast",
                "--res",
                "32",
                "--spp",
                "8",
                "--roughness",
                "0.2,0.7",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_exr_writer_full(tmp_path, capsys, full_exr):
    out = tmp_path / "ex"
    code = main(["exemplars", "--point-light", "--res", "16", "--spp", "1", "--out", str(out)])
    line = _one_line(capsys.readouterr().err, "exemplars")
    assert code == 2
    assert f"writing {out / 'r0.100.exr'};" in line, line
    assert f"free space on {mount_point(tmp_path)} or choose another --out" in line
    assert _leftovers(tmp_path) == []


def test_json_writer_full(tmp_path, capsys, full_json, exemplar_dir):
    out = tmp_path / "env.json"
    code = main(["extract-sg", str(exemplar_dir), "--out", str(out), "--iters", "2", "--max-lobes", "4"])
    line = _one_line(capsys.readouterr().err, "extract-sg")
    assert code == 2
    assert f"writing {out};" in line, line
    assert _leftovers(tmp_path) == []


def test_estimate_output_directory_full(tmp_path, capsys, monkeypatch):
    from fakes import GRID, use_fake_model, write_pair

    inputs = write_pair(tmp_path / "in", seed=0)
    use_fake_model(monkeypatch, GRID)
    state = {"writes": 0}
    import OpenEXR

    real = OpenEXR.File

    class FullAfterTwo:  # the disk fills up in the middle of the estimate's outputs
        def __init__(self, header, pixels):
            self._f = real(header, pixels)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, path):
            state["writes"] += 1
            if state["writes"] > 2:
                Path(path).write_bytes(b"half")
                raise RuntimeError(f'Failed to write pixel data to image file "{path}". {ENOSPC_TEXT}.')
            self._f.write(path)

    monkeypatch.setattr(
        OpenEXR,
        "File",
        lambda *a, **k: FullAfterTwo(*a, **k) if a and isinstance(a[0], dict) else real(*a, **k),
    )
    out = tmp_path / "est"
    code = main(
        [
            "estimate",
            "--flash",
            str(inputs / "flash.exr"),
            "--noflash",
            str(inputs / "noflash.exr"),
            "--out",
            str(out),
            "--checkpoint",
            str(inputs / "flash.exr"),
        ]
    )
    line = _one_line(capsys.readouterr().err, "estimate")
    assert code == 2 and state["writes"] == 3
    written = line.split(" writing ", 1)[1].split(";", 1)[0]
    assert written.startswith(str(out) + os.sep) and written.endswith(".exr"), line
    assert ".partial" not in written and ".tmp" not in written
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["in"], _leftovers(tmp_path)


def test_generate_sample_full(tmp_path, capsys, full_exr):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text("""
[dataset]
seed = 7
count = 2
resolution = 16

[render]
renderer = "fast"
spp = 2
fast_mode = "quadrature"
fast_spp = 4

[exemplars]
env_roughness = [0.5]
point_roughness = [0.3]

[[materials]]
type = "procedural"
families = ["tiles"]

[[environments]]
type = "procedural"
""")
    out = tmp_path / "ds"
    code = main(["generate", str(cfg), "--out", str(out)])
    line = _one_line(capsys.readouterr().err, "generate")
    assert code == 2
    written = line.split(" writing ", 1)[1].split(";", 1)[0]
    assert written.startswith(str(out / "samples") + os.sep) and written.endswith(".exr"), line
    assert ".partial" not in written and ".tmp" not in written
    # complete files only: no temporaries, no sample directory (the data set resumes with --resume)
    left = _leftovers(out)
    assert not [p for p in left if "/." in f"/{p}"], left
    assert not (out / "samples" / "000000").exists()


# -- a real full file system (root only) ------------------------------------------------------------


@pytest.fixture
def tiny_tmpfs(tmp_path):
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_real_tmpfs(tiny_tmpfs, capsys, exemplar_dir):
    (tiny_tmpfs / "fill").write_bytes(b"\0" * (64 * 1024 - 4096))  # one page left
    cases = [
        (
            "exemplars",
            ["--point-light", "--res", "64", "--spp", "1", "--out", str(tiny_tmpfs / "ex")],
            tiny_tmpfs / "ex" / "r0.100.exr",
        ),
        (
            "extract-sg",
            [str(exemplar_dir), "--out", str(tiny_tmpfs / "env.json"), "--iters", "2"],
            tiny_tmpfs / "env.json",
        ),
    ]
    (tiny_tmpfs / "fill2").write_bytes(b"\0" * 4096)  # now completely full
    for command, args, expect in cases:
        code = main([command, *args])
        line = _one_line(capsys.readouterr().err, command)
        assert code == 2
        assert f"no space left on device {tiny_tmpfs} writing " in line
        if expect is not None:
            assert f"writing {expect};" in line
        assert sorted(p.name for p in tiny_tmpfs.iterdir()) == ["fill", "fill2"]
