"""Fault injection (issue 16, part A): real kills, damaged files and concurrent writers against the
real ``ebr`` processes. Slow (subprocesses, each importing torch and Mitsuba): ``make test-all``.

Cases (16, checked by :func:`test_zz_case_counts`):

* 2 kills of ``ebr generate --workers 2`` (SIGKILL, SIGTERM of the parent): no worker and no
  resource tracker outlives it, ``--resume`` completes the set, it verifies and its first samples
  equal those of a straight run (:func:`test_kill_generate`);
* 4 kills of ``ebr train`` (:func:`test_kill_train`): SIGKILL before the first checkpoint, then
  ``--resume``, or a plain rerun; SIGKILL after a checkpoint, mid-way through the second phase;
  SIGKILL in the middle of a checkpoint write. Each time the run completes, ``log.csv`` has each
  step once, ``summary.json`` every phase, and no temporaries are left;
* 7 damaged data sets (:func:`test_train_refuses_damaged_data`): 16 flipped bytes or 1 flipped
  bit in an EXR, a truncated EXR, a deleted ``manifest.json`` or ``sample.json``, garbage in
  ``sample.json`` or ``dataset.json``: ``ebr train`` exits 2 with one line naming the file;
* 3 second writers (:func:`test_second_process_is_refused`): ``ebr generate --resume``, ``ebr
  estimate`` and ``ebr train`` into an output another live process is writing: exit 2, one line,
  and the first process finishes (or is stopped) undisturbed.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import tomllib

from ebr_mitsuba.data import store
from ebr_mitsuba.data.verify import verify
from ebr_mitsuba.fsutil import lock_path

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")]

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
ENV = dict(os.environ, TQDM_DISABLE="1", OMP_NUM_THREADS="1")
EBR = [sys.executable, "-m", "ebr_mitsuba.cli"]

GENERATE_KILLS = ["SIGKILL", "SIGTERM"]
TRAIN_KILLS = ["before-checkpoint-resume", "before-checkpoint-restart", "after-checkpoint", "during-write"]
DAMAGES = [
    "16 bytes",
    "1 bit",
    "truncated exr",
    "no manifest.json",
    "no sample.json",
    "bad sample.json",
    "bad dataset.json",
]
WRITERS = ["generate", "estimate", "train"]


# -- helpers ------------------------------------------------------------------------------------------


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


def children(pid: int) -> dict[int, str]:
    """{pid: command line} of the live children of ``pid``."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and alive(int(d.name)):
            out[int(d.name)] = cmd
    return out


def wait_for(condition, timeout: float = 120.0, what: str = "condition", proc=None) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"process ended (rc {proc.returncode}) before {what}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def one_error_line(stderr: str, command: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ebr {command}: error: "), lines
    return lines[0]


def train_config(path: Path, data: Path, stages: dict, use_exemplars: bool = True, **train) -> Path:
    """configs/train_tiny.toml with the given stages and [train] options, written to ``path``."""
    doc = tomllib.loads((CONFIGS / "train_tiny.toml").read_text())
    doc["data"] = {"train": str(data)}
    doc["train"].update(batch_size=2, log_every=1, threads=1, **train)
    doc["stages"] = {"lighting": 0, "diffuse": 0, "specular": 0, "refinement": 0, "finetune": 0, **stages}
    doc["model"]["use_exemplars"] = use_exemplars

    def value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for key, table in doc.items():
        if isinstance(table, dict):
            lines += [f"[{key}]"] + [f"{k} = {value(v)}" for k, v in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def log_steps(out: Path) -> list[tuple[str, int]]:
    if not (out / "log.csv").is_file():
        return []
    with open(out / "log.csv", newline="") as f:
        rows = list(csv.reader(f))[1:]
    return [(r[0], int(r[1])) for r in rows if len(r) >= 2 and r[1].isdigit()]


def check_finished_run(out: Path, stages: dict) -> None:
    expected = [(phase, s) for phase, n in stages.items() for s in range(1, n + 1)]
    assert log_steps(out) == expected  # every step once, in order
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["phases"]) == list(stages)
    assert (out / "model.pt").is_file()
    assert not [p.name for p in out.rglob(".*")]  # no temporaries
    assert not lock_path(out).exists()


# -- ebr generate ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("sig", GENERATE_KILLS)
def test_kill_generate(tiny, tmp_path, sig):
    out = tmp_path / "G"
    cmd = EBR + [
        "generate",
        str(CONFIGS / "data_tiny.toml"),
        "--out",
        str(out),
        "--count",
        "10",
        "--workers",
        "2",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)
    workers = {}

    def started():
        workers.update(children(proc.pid))
        spawned = [p for p, c in workers.items() if "spawn_main" in c]
        return len(spawned) == 2 and any(store.is_complete(out, i) for i in range(10))

    try:
        wait_for(started, what="two workers and a first sample", proc=proc)
    except BaseException:
        proc.kill()
        raise
    assert any("resource_tracker" in c for c in workers.values()), workers
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == (-9 if sig == "SIGKILL" else 143), err
    deadline = time.monotonic() + 10
    while any(alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    orphans = {p: c[:80] for p, c in workers.items() if alive(p)}
    assert not orphans, f"outlived the parent: {orphans}"
    assert not (out / "index.json").exists()
    if sig == "SIGTERM":
        assert "terminated (SIGTERM)" in err
        assert "Traceback" not in err, err  # one line, not the executor thread's report
        assert not [p for p in (out / "samples").iterdir() if p.name.endswith(".partial")]
    report = verify(out)
    assert not report.ok and "--resume" in report.errors[0]
    result = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, env=ENV, timeout=300)
    assert result.returncode == 0, result.stderr
    assert verify(out).ok
    for i in range(4):  # the straight run of the same config
        a, b = tiny / store.sample_dirname(i), out / store.sample_dirname(i)
        assert (a / "manifest.json").read_bytes() == (b / "manifest.json").read_bytes(), i


# -- ebr train ------------------------------------------------------------------------------------------

KILL_IN_SAVE = textwrap.dedent("""
    import io, os, signal, sys
    import torch
    real, calls = torch.save, [0]
    def save(obj, f, *args, **kwargs):
        calls[0] += 1
        if calls[0] == int(os.environ["EBR_TEST_KILL_AT_SAVE"]):  # half the bytes, then SIGKILL
            buf = io.BytesIO()
            real(obj, buf, *args, **kwargs)
            with open(f, "wb") as fh:
                fh.write(buf.getvalue()[: len(buf.getvalue()) // 2])
            os.kill(os.getpid(), signal.SIGKILL)
        return real(obj, f, *args, **kwargs)
    torch.save = save
    from ebr_mitsuba.cli import main
    sys.exit(main(sys.argv[1:]))
""")


@pytest.mark.parametrize("case", TRAIN_KILLS)
def test_kill_train(tiny, tmp_path, case):
    out = tmp_path / "run"
    if case.startswith("before-checkpoint"):
        stages, opts = {"lighting": 200}, {"checkpoint_every": 1000}  # the phase end is the first one
    elif case == "after-checkpoint":
        stages, opts = {"lighting": 20, "diffuse": 150}, {"checkpoint_every": 10}
    else:
        stages, opts = {"lighting": 30}, {"checkpoint_every": 10}
    cfg = train_config(tmp_path / "t.toml", tiny, stages, use_exemplars=False, **opts)
    args = ["train", str(cfg), "--out", str(out)]
    if case == "during-write":  # the 2nd torch.save (step 20) writes half its bytes, then SIGKILL
        proc = subprocess.Popen(
            [sys.executable, "-c", KILL_IN_SAVE] + args,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=dict(ENV, EBR_TEST_KILL_AT_SAVE="2"),
        )
        proc.wait(timeout=300)
        assert proc.returncode == -9
        assert [p.name for p in out.glob(".last.*.tmp.pt")], "no half-written checkpoint"
    else:
        proc = subprocess.Popen(EBR + args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)
        try:
            if case == "after-checkpoint":  # in the second phase, after its first checkpoint
                wait_for(lambda: ("diffuse", 13) in log_steps(out), what="diffuse step 13", proc=proc)
            else:
                wait_for(lambda: len(log_steps(out)) >= 3, what="three steps", proc=proc)
                assert not (out / "last.pt").exists()
        finally:
            proc.kill()
            proc.wait()
    resume = [] if case == "before-checkpoint-restart" else ["--resume"]
    result = subprocess.run(EBR + args + resume, capture_output=True, text=True, env=ENV, timeout=300)
    assert result.returncode == 0, result.stderr
    check_finished_run(out, stages)


# -- damaged data ---------------------------------------------------------------------------------------


def damage(root: Path, kind: str) -> str:
    """Damage the data set at ``root``; returns the file the error must name."""
    s = root / "samples/000002"
    if kind in ("16 bytes", "1 bit"):
        path = s / ("maps/diffuse.exr" if kind == "16 bytes" else "exemplars/env_1.exr")
        data = bytearray(path.read_bytes())
        for i in range(16 if kind == "16 bytes" else 1):
            data[len(data) // 2 + i] ^= 0xFF if kind == "16 bytes" else 0x04
        path.write_bytes(bytes(data))
    elif kind == "truncated exr":
        path = s / "flash_only/flash.exr"
        path.write_bytes(path.read_bytes()[:-100])
    elif kind == "no manifest.json":
        path = s / "manifest.json"
        path.unlink()
    elif kind == "no sample.json":
        path = s / "sample.json"
        path.unlink()
    elif kind == "bad sample.json":
        path = s / "sample.json"
        path.write_text(path.read_text()[:-30])
    else:
        path = root / "dataset.json"
        path.write_text("{ not json")
    return str(path)


@pytest.mark.parametrize("kind", DAMAGES)
def test_train_refuses_damaged_data(tiny, tmp_path, kind):
    data = tmp_path / "data"
    shutil.copytree(tiny, data)
    named = damage(data, kind)
    cfg = train_config(tmp_path / "t.toml", data, {"lighting": 2}, checkpoint_every=1)
    result = subprocess.run(
        EBR + ["train", str(cfg), "--out", str(tmp_path / "run")],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=300,
    )
    assert result.returncode == 2, result.stderr
    line = one_error_line(result.stderr, "train")
    assert named in line and "ebr generate" in line, line
    assert not (tmp_path / "run").exists()


# -- concurrent writers -------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", WRITERS)
def test_second_process_is_refused(tiny, tmp_path, command):
    out = tmp_path / "out"
    photos = tiny / "samples/000000/photos"
    if command == "generate":
        argv = ["generate", str(CONFIGS / "data_tiny.toml"), "--out", str(out), "--count", "40"]
        second = argv + ["--resume"]
    elif command == "estimate":
        argv = [
            "estimate",
            "--flash",
            str(photos / "flash.png"),
            "--noflash",
            str(photos / "noflash.png"),
            "--out",
            str(out),
        ]
        second = argv
    else:
        argv = [
            "train",
            str(train_config(tmp_path / "t.toml", tiny, {"lighting": 2000}, checkpoint_every=1000)),
            "--out",
            str(out),
        ]
        second = argv + ["--resume"]
    first = subprocess.Popen(
        EBR + argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV
    )
    try:
        wait_for(lock_path(out).exists, what="the first process's lock", proc=first)
        result = subprocess.run(EBR + second, capture_output=True, text=True, env=ENV, timeout=300)
        assert first.poll() is None, "the first process ended before the second one was checked"
        assert result.returncode == 2, result.stderr
        line = one_error_line(result.stderr, command)
        assert f"in use by ebr {command} (pid {first.pid})" in line, line
        if command == "estimate":  # the first one finishes and is the only one to write
            _, err = first.communicate(timeout=300)
            assert first.returncode == 0 and "wrote" in err, err
        else:
            first.send_signal(signal.SIGTERM)
            first.communicate(timeout=60)
            assert first.returncode == 143
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate()
    assert not lock_path(out).exists()  # released (and removed) by the first process


# -- counts -------------------------------------------------------------------------------------------------


def test_zz_case_counts():
    """The module docstring's counts: 2 generate kills, 4 train kills, 7 damages, 3 writers."""
    counts = {
        "generate kills": len(GENERATE_KILLS),
        "train kills": len(TRAIN_KILLS),
        "damaged data sets": len(DAMAGES),
        "second writers": len(WRITERS),
    }
    print("fault-injection cases:", counts, "total", sum(counts.values()))
    assert counts == {"generate kills": 2, "train kills": 4, "damaged data sets": 7, "second writers": 3}
    assert sum(counts.values()) == 16
    assert "Cases (16," in (__doc__ or "")
