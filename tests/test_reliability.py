"""Faults, interruptions and first contact (issue 16, part A), fast cases of the default suite.

One test (or parametrised family) per item; the real kills are in tests/test_faults.py (slow):

1. training checks what it reads: a damaged sample is refused by name, exit 2, one line
   (:func:`test_train_refuses_a_damaged_sample_by_name`);
2. a run stopped before its first checkpoint resumes or restarts
   (:func:`test_train_stopped_before_the_first_checkpoint_resumes_or_restarts`); a resume keeps
   ``log.csv`` free of duplicates, ``summary.json`` complete and no temporaries
   (:func:`test_resume_keeps_log_summary_and_no_temporaries`); same-seed runs are bit-identical
   (:func:`test_same_seed_runs_are_bit_identical`);
3. ``ebr dataset verify`` explains an interrupted run or ``--count`` extension
   (:func:`test_verify_explains_an_interrupted_run`, :func:`test_verify_refuses_an_interrupted_extension`);
4. pool workers die with their parent (:func:`test_worker_dies_with_its_parent`, both the
   ``prctl`` and the watchdog branch) and SIGTERM becomes an exception that runs the clean-ups
   (:func:`test_sigterm_becomes_an_exception`);
5. one writer per output (:func:`test_output_lock_is_exclusive_and_dies_with_its_holder`,
   :func:`test_second_writer_is_refused_with_one_line` for generate, estimate and train);
15. under torchrun only rank 0 prints (:func:`test_only_rank_0_prints`).
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

import numpy as np
import pytest
import tomllib
import torch

from ebr_mitsuba.cli import main
from ebr_mitsuba.data import store
from ebr_mitsuba.errors import BusyError, InputError
from ebr_mitsuba.fsutil import OutputLock, Terminated, lock_path, sigterm_as_exit

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


# -- helpers ------------------------------------------------------------------------------------------


def train_doc(data: Path, **stages) -> dict:
    """configs/train_tiny.toml cut down: lighting 2 steps, other phases as given (default 0)."""
    doc = tomllib.loads((CONFIGS / "train_tiny.toml").read_text())
    doc["data"] = {"train": str(data)}
    doc["train"].update(batch_size=2, log_every=1, checkpoint_every=1, threads=1)
    doc["stages"] = {
        "lighting": 2,
        "diffuse": 0,
        "specular": 0,
        "refinement": 0,
        "finetune": 0,
        "finetune_samples": 2,
        **stages,
    }
    doc["extract"] = {"iters": 3, "max_lobes": 4}
    return doc


def write_toml(doc: dict, path: Path) -> Path:
    """A TOML file of ``doc`` (scalars, lists and one level of inline tables)."""

    def value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for key, table in doc.items():
        if isinstance(table, dict):
            lines.append(f"[{key}]")
            lines += [f"{k} = {value(v)}" for k, v in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def train(doc: dict, out: Path, resume: bool = False, **kwargs) -> dict:
    from ebr_mitsuba.model.config import parse_config
    from ebr_mitsuba.train.trainer import Trainer

    return Trainer(parse_config(doc, "t.toml"), out, resume=resume, **kwargs).run()


def error_lines(err: str) -> list[str]:
    """The lines of a captured stderr, progress-bar redraws (``\\r`` segments) dropped."""
    return [seg for line in err.split("\n") if (seg := line.split("\r")[-1].strip())]


def log_rows(out: Path) -> list[tuple]:
    """(phase, step, loss, terms) of every row of a run's log.csv (wall-time columns dropped)."""
    with open(out / "log.csv", newline="") as f:
        return [tuple(r[:4]) for r in list(csv.reader(f))[1:]]


def weights(path: Path) -> dict:
    return torch.load(path, weights_only=False)["model"]


def same_weights(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[n].keys() == b[n].keys() and all(torch.equal(a[n][k], b[n][k]) for k in a[n]) for n in a
    )


def interrupt_at(monkeypatch, call: int):
    """Make the ``call``-th loss evaluation raise KeyboardInterrupt (a stop mid-step)."""
    from ebr_mitsuba.train.trainer import Trainer

    original, calls = Trainer._loss, {"n": 0}

    def loss(self, *args):
        calls["n"] += 1
        if calls["n"] == call:
            raise KeyboardInterrupt
        return original(self, *args)

    monkeypatch.setattr(Trainer, "_loss", loss)
    return lambda: monkeypatch.setattr(Trainer, "_loss", original)


# -- 1. training checks what it reads --------------------------------------------------------------------


def _flip(path: Path, nbytes: int = 0, bit: bool = False) -> None:
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    if bit:
        data[mid] ^= 0x01
    for i in range(nbytes):
        data[mid + i] ^= 0xA5
    path.write_bytes(bytes(data))


DAMAGE = {
    # name: (damage(root), text the error line must contain)
    "16 bytes flipped in an EXR": (
        lambda r: _flip(r / "samples/000001/maps/diffuse.exr", 16),
        "samples/000001/maps/diffuse.exr: checksum differs",
    ),
    "1 bit flipped in an EXR": (
        lambda r: _flip(r / "samples/000002/exemplars/env_0.exr", bit=True),
        "samples/000002/exemplars/env_0.exr: checksum differs",
    ),
    "truncated EXR": (
        lambda r: (p := r / "samples/000001/flash_only/flash.exr").write_bytes(p.read_bytes()[:200]),
        "samples/000001/flash_only/flash.exr: size differs",
    ),
    "deleted manifest.json": (
        lambda r: (r / "samples/000003/manifest.json").unlink(),
        "samples/000003/manifest.json: missing",
    ),
    "deleted sample.json": (
        lambda r: (r / "samples/000000/sample.json").unlink(),
        "samples/000000/sample.json: missing",
    ),
    "edited manifest.json": (
        lambda r: (p := r / "samples/000001/manifest.json").write_text(
            p.read_text().replace('"bytes": ', '"bytes": 1')
        ),
        "samples/000001/manifest.json: its SHA-256",
    ),
    "garbage index.json": (
        lambda r: (r / "index.json").write_bytes(b"\x00{garbage"),
        "index.json: unreadable",
    ),
    "deleted dataset.json": (lambda r: (r / "dataset.json").unlink(), "dataset.json: missing"),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_train_refuses_a_damaged_sample_by_name(tiny, tmp_path, capsys, damage):
    """Issue 16.1: ``ebr train`` refuses (exit 2, one line naming the file and the fix) what
    ``ebr dataset verify`` flags, before it trains or writes anything."""
    data = tmp_path / "data"
    shutil.copytree(tiny, data)
    hurt, needle = DAMAGE[damage]
    hurt(data)
    cfg = write_toml(train_doc(data), tmp_path / "t.toml")
    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["train", str(cfg), "--out", str(out)]) == 2
    lines = error_lines(capsys.readouterr().err)
    assert len(lines) == 1, lines
    assert lines[0].startswith("ebr train: error: ") and needle in lines[0], lines
    assert "ebr generate" in lines[0]  # the fix
    assert not out.exists() and not lock_path(out).exists()  # nothing written, the lock released
    if damage != "deleted dataset.json":
        from ebr_mitsuba.data.verify import verify

        assert not verify(data).ok  # verify flags the same damage


def test_torch_dataset_refuses_an_interrupted_extension(tiny, tmp_path):
    from ebr_mitsuba.data.dataset import GeneratedDataset

    data = tmp_path / "data"
    shutil.copytree(tiny, data)
    _pretend_extension(data, 6)
    with pytest.raises(InputError, match="--count 6 --resume"):
        GeneratedDataset(data)


# -- 2. resume, restart, determinism ------------------------------------------------------------------


def test_train_stopped_before_the_first_checkpoint_resumes_or_restarts(tiny, tmp_path, monkeypatch):
    """Issue 16.2: stopped in step 1 (no last.pt yet, a temporary of the checkpoint write left
    behind): ``--resume`` starts at step 0, and so does a plain rerun; both give the straight
    run's weights."""
    doc = train_doc(tiny)
    train(doc, tmp_path / "straight")
    expected = weights(tmp_path / "straight" / "model.pt")
    for how in ("resume", "restart"):
        out = tmp_path / how
        restore = interrupt_at(monkeypatch, 1)
        with pytest.raises(KeyboardInterrupt):
            train(doc, out)
        restore()
        (out / ".last.k1ll3d.pt.tmp.pt").write_bytes(b"half a checkpoint")  # as a SIGKILL leaves it
        assert not (out / "last.pt").exists() and (out / "config.json").is_file()
        messages = []
        train(doc, out, resume=how == "resume", log=messages.append)
        assert same_weights(weights(out / "model.pt"), expected)
        assert log_rows(out) == log_rows(tmp_path / "straight")
        assert not [p for p in out.rglob(".*")]
        if how == "resume":
            assert any("no checkpoint yet" in m for m in messages), messages
    # a directory with a checkpoint still needs --resume; another config is still refused
    with pytest.raises(InputError, match="not empty; pass --resume"):
        train(doc, tmp_path / "resume")
    (tmp_path / "resume" / "last.pt").unlink()
    (tmp_path / "resume" / "model.pt").unlink()
    other = dict(doc, train={**doc["train"], "lr": 5e-4})
    for name in ("after_lighting.pt", "summary.json"):
        (tmp_path / "resume" / name).unlink()
    with pytest.raises(InputError, match="another config"):
        train(other, tmp_path / "resume", resume=True)


def test_resume_keeps_log_summary_and_no_temporaries(tiny, tmp_path, monkeypatch):
    """Issue 16.2: a resume does not duplicate log.csv rows, keeps the earlier phases in
    summary.json, removes the temporaries a killed checkpoint write left, and ends with the
    straight run's weights."""
    doc = train_doc(tiny, diffuse=4)
    doc["model"]["use_exemplars"] = False  # no exemplar-selection cache: seconds
    doc["train"].update(checkpoint_every=2)
    train(doc, tmp_path / "straight")
    out = tmp_path / "resumed"
    restore = interrupt_at(monkeypatch, 2 + 4)  # lighting 2 steps, diffuse: stopped in step 4
    with pytest.raises(KeyboardInterrupt):
        train(doc, out)
    restore()
    assert torch.load(out / "last.pt", weights_only=False)["step"]["step"] == 2  # diffuse step 2
    (out / ".last.s1gk1ll.pt.tmp.pt").write_bytes(b"half a checkpoint")
    (out / "cache").mkdir(exist_ok=True)
    (out / "cache" / ".000001.x.npz.tmp.npz").write_bytes(b"half a cache file")
    train(doc, out, resume=True)
    assert log_rows(out) == log_rows(tmp_path / "straight")  # no duplicated rows
    straight = json.loads((tmp_path / "straight" / "summary.json").read_text())
    resumed = json.loads((out / "summary.json").read_text())
    assert list(resumed["phases"]) == ["lighting", "diffuse"] == list(straight["phases"])
    for phase in resumed["phases"]:
        assert resumed["phases"][phase]["final_loss"] == straight["phases"][phase]["final_loss"]
    assert not [p for p in out.rglob(".*")]
    assert same_weights(weights(out / "model.pt"), weights(tmp_path / "straight" / "model.pt"))


def test_same_seed_runs_are_bit_identical(tiny, tmp_path):
    """Issue 16.2: two uninterrupted runs with the same seed give the same bits, stage 2 included
    (SG extraction in Dr.Jit, whose multi-threaded scatter-adds vary: conftest gives Dr.Jit every
    core, the trainer runs it on one)."""
    import drjit as dr

    doc = train_doc(tiny, lighting=1, finetune=1)
    threads = dr.thread_count()
    for run in ("a", "b"):
        train(doc, tmp_path / run)
        assert dr.thread_count() == threads  # restored
    a, b = tmp_path / "a", tmp_path / "b"
    assert same_weights(weights(a / "model.pt"), weights(b / "model.pt"))
    assert log_rows(a) == log_rows(b)
    files = sorted((a / "cache" / "stage2").glob("*.npz"))
    assert len(files) == 2
    for f in files:
        x, y = dict(np.load(f)), dict(np.load(b / "cache" / "stage2" / f.name))
        assert x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x), f.name


# -- 3. verify explains interrupted runs ----------------------------------------------------------------


def _pretend_extension(root: Path, count: int) -> None:
    """What an interrupted ``--count`` extension leaves: dataset.json rewritten with the new count
    (it is written first), index.json still the old one (it is written last)."""
    doc = store.read_json(root / "dataset.json")
    doc["count"] = count
    (root / "dataset.json").write_text(store.dumps(doc))


def test_verify_explains_an_interrupted_run(tiny, tmp_path, capsys):
    """Issue 16.3: no index.json: how many samples are complete, and that --resume finishes it."""
    data = tmp_path / "data"
    shutil.copytree(tiny, data)
    (data / "index.json").unlink()
    shutil.rmtree(data / "samples/000003")
    capsys.readouterr()
    assert main(["dataset", "verify", str(data)]) == 2
    err = capsys.readouterr().err
    assert "interrupted with 3 of 4 samples complete" in err and "--resume" in err, err


def test_verify_refuses_an_interrupted_extension(tiny, tmp_path, capsys):
    """Issue 16.3: dataset.json 6, index.json 4 (an interrupted --count extension) is not OK."""
    data = tmp_path / "data"
    shutil.copytree(tiny, data)
    _pretend_extension(data, 6)
    capsys.readouterr()
    assert main(["dataset", "verify", str(data)]) == 2
    err = capsys.readouterr().err
    assert "interrupted --count extension with 4 of 6 samples complete" in err, err
    assert "--count 6 --resume" in err


# -- 4. workers die with their parent; SIGTERM runs the clean-ups ------------------------------------------


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")  # a zombie is dead, only not yet reaped


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("use_prctl", [True, False], ids=["prctl", "watchdog"])
def test_worker_dies_with_its_parent(tmp_path, use_prctl):
    """Issue 16.4: a process that called die_with_parent ends soon after its parent is SIGKILLed
    (prctl(PR_SET_PDEATHSIG) at once; the watchdog within its poll interval)."""
    ready = tmp_path / "ready"
    child = textwrap.dedent(f"""
        import os, pathlib, time
        from ebr_mitsuba.data.workers import die_with_parent
        die_with_parent(os.getppid(), poll=0.2, use_prctl={use_prctl})
        pathlib.Path({str(ready)!r}).write_text(str(os.getpid()))
        time.sleep(60)
    """)
    parent = textwrap.dedent(f"""
        import subprocess, sys, time
        subprocess.Popen([sys.executable, "-c", {child!r}])
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", parent])
    try:
        deadline = time.monotonic() + 30
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.05)
        pid = int(ready.read_text())
        assert _alive(pid)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 5
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(pid), f"worker {pid} outlived its parent"


def test_sigterm_becomes_an_exception():
    """Issue 16.4: inside sigterm_as_exit a SIGTERM raises Terminated (exit code 143) in the main
    thread, so finally clauses (pool shutdown, atomic writes, locks) run; the handler is restored."""
    before = signal.getsignal(signal.SIGTERM)
    cleaned = []
    with pytest.raises(Terminated) as info:
        with sigterm_as_exit():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
            finally:
                cleaned.append(True)
    assert info.value.code == 143 and cleaned == [True]
    assert signal.getsignal(signal.SIGTERM) is before


def test_stopping_the_pool_terminates_its_workers():
    """Issue 16.4: the pool's error path (a worker's error, Ctrl-C, SIGTERM as Terminated) stops
    the workers at once instead of letting them finish their samples."""
    import multiprocessing as mp

    from ebr_mitsuba.data import workers

    ctx = mp.get_context("spawn")
    sleepers = [ctx.Process(target=time.sleep, args=(60,)) for _ in range(2)]
    for p in sleepers:
        p.start()
    workers.stop_workers(timeout=5.0)
    assert not any(p.is_alive() for p in sleepers) and not mp.active_children()


# -- 5. one writer per output -------------------------------------------------------------------------


def test_output_lock_is_exclusive_and_dies_with_its_holder(tmp_path):
    """Issue 16.5: a second holder is refused with one line naming the output and the holder; a
    released or SIGKILLed holder's lock is free again (no stale lock)."""
    out = tmp_path / "out"
    with OutputLock(out, "ebr test"):
        with pytest.raises(BusyError, match=r"out: in use by ebr test \(pid \d+\)"):
            OutputLock(out, "other").acquire()
    assert not lock_path(out).exists()
    code = (
        f"from ebr_mitsuba.fsutil import OutputLock; lock = OutputLock({str(out)!r}, 'ebr x').acquire()\n"
        f"print('held', flush=True); import time; time.sleep(60)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(BusyError, match="in use by ebr x"):
            OutputLock(out).acquire()
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
    assert lock_path(out).exists()  # the killed holder's file is left, its lock is not
    with OutputLock(out):
        pass


@pytest.mark.parametrize("command", ["generate", "estimate", "train"])
def test_second_writer_is_refused_with_one_line(tiny, tmp_path, capsys, command):
    """Issue 16.5: while another process holds an output, ``ebr generate --resume``, ``ebr
    estimate`` and ``ebr train`` into it are refused (exit 2, one line) and write nothing."""
    out = tmp_path / "out"
    if command == "generate":
        shutil.copytree(tiny, out)
        argv = ["generate", str(CONFIGS / "data_tiny.toml"), "--out", str(out), "--resume"]
    elif command == "estimate":
        sample = tiny / "samples/000000/photos"
        argv = [
            "estimate",
            "--flash",
            str(sample / "flash.png"),
            "--noflash",
            str(sample / "noflash.png"),
            "--out",
            str(out),
        ]
    else:
        argv = ["train", str(write_toml(train_doc(tiny), tmp_path / "t.toml")), "--out", str(out)]
    before = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    with OutputLock(out, "ebr first"):
        capsys.readouterr()
        assert main(argv) == 2
        lines = error_lines(capsys.readouterr().err)
        assert (
            len(lines) == 1
            and lines[0].startswith(f"ebr {command}: error: ")
            and "in use by ebr first" in lines[0]
        ), lines
        after = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
        assert after == sorted(before + [lock_path(out).relative_to(tmp_path).as_posix()])  # the holder's


# -- 15. rank 0 prints --------------------------------------------------------------------------------


def test_only_rank_0_prints(tiny, tmp_path, monkeypatch):
    """Issue 16.15: rank 1 of a (simulated) two-process run prints nothing and draws no bars."""
    from ebr_mitsuba.train import ddp

    monkeypatch.setattr(ddp, "init_distributed", lambda device: ddp.DistInfo(rank=1, world=2))
    monkeypatch.setattr(ddp, "barrier", lambda info: None)
    monkeypatch.setattr(ddp, "wrap", lambda module, info, device: module)
    monkeypatch.setattr(ddp, "all_mean", lambda value, info: value)
    printed, bars = [], []

    def progress(*args, **kwargs):
        bars.append(kwargs.get("desc"))
        raise AssertionError("rank 1 drew a progress bar")

    out = tmp_path / "run"
    doc = train_doc(tiny, lighting=1)
    train(doc, out, log=printed.append, progress=progress)
    assert printed == [] and bars == []
    assert not out.exists() and not lock_path(out).exists()  # rank 1 writes nothing either
