"""The training loop of ``ebr train``: phases, losses, logging, checkpoints, resume, DDP.

**EBREnv** (``kind = "ebrenv"``), phases in order (``[stages]`` gives the steps; 0 skips):

==============  ==============================  ===============================================
phase           trains (others frozen)          inputs and loss
==============  ==============================  ===============================================
``lighting``    lighting net                    shots → exemplars + flash-only;
                                                L1 of ``log(x + ε)`` against the data set's
                                                exemplars and (near) flash-only image
``diffuse``     diffuse net (joint net without  stage 1: GT flash-only, exemplars selected
                the cascade)                    under the GT env (cache); L1 normal + diffuse
                                                (all four maps for the joint net)
``specular``    specular net                    stage 1; L1 specular + roughness
``refinement``  refinement net                  stage 1, residuals under GT env + fitted flash;
                                                L1 of all maps (+ ``render`` × rendering loss)
``finetune``    the whole cascade               stage 2: the lighting net's flash-only image,
                                                extracted SGs and their selections (cache,
                                                ``finetune_samples`` samples); L1 of the final
                                                and the first-stage maps (+ rendering loss)
==============  ==============================  ===============================================

**Dual loss** (``kind = "dualloss"``): one phase ``dualloss`` of ``[train].steps`` steps on a
five-light data set: parameter L1 + ``render`` × the rendering loss (10 view/light pairs, 5 with a
forced highlight, Dr.Jit renderer through ``dr.wrap``).

**MAIR** (``kind = "mair"``, a ``multi-view`` data set of texture-space views, i.e. made by the
fast renderer): MAIR's stages in turn, ``[stages]`` giving their steps (:class:`.phases.MAIRPhase`):
``normal`` (g1 + g2 on the normals), ``lighting`` (g4 on the per-pixel incident radiance + g5 on
the visibility), ``brdf`` (g3 diffuse, g2 specular and roughness, the multi-view re-render loss);
weights in ``[loss]`` (:class:`~ebr_mitsuba.model.config.MAIRLossConfig`). The network sees the 9
views times their in-frame weights, as a rectified camera capture shows them.

**Near-far** (``[model].capture = "near-far"``, a ``near-far`` data set): the lighting net takes
the four shots (flash, no-flash, far flash, far no-flash; :data:`.data.CAPTURE_SHOTS`) and still
predicts the near exemplars and the near flash-only image; the diffuse and specular nets see the
near images only, as at inference; the refinement gets the four photos and their four residuals,
the far pair rendered from the far camera with its flash scale fitted to the far flash-only image
``max(far flash − far no-flash, 0)`` of the photos (:func:`.renders.far_flash_only`) in every
phase, stage 1 included, because inference has no other. The caches are the near ones (the
selection compares with the near no-flash photo and flash-only image); stage 2 runs the lighting
net on all four shots. A model refuses a data set of the other setup before any work.

Every phase: Adam, learning rate decaying from its initial value to ``lr_final`` on a cosine;
batches drawn from a seeded permutation per epoch (``torch.Generator``, state checkpointed);
every ``log_every`` steps one read-back of the loss → CSV row (``log.csv``: phase, step, loss,
per-term losses, lr, samples/s, seconds) and the progress bar; every ``checkpoint_every`` steps
and at each phase end ``last.pt`` (atomic; at a phase end also ``after_<phase>.pt``, weights
only, for initialising other runs). The run ends with ``model.pt`` and ``summary.json``.
``--resume`` continues from ``last.pt`` at the step after the one saved (weights, optimizer,
generators, the summary of the phases before it, the phase's elapsed seconds), reusing the
caches; ``log.csv`` keeps the rows up to the checkpoint (the later ones are redone).

**Output.** Rank 0 locks ``--out`` for the run (:class:`ebr_mitsuba.fsutil.OutputLock`; a second
run into it is refused) and removes the temporaries a killed atomic write left there. A
directory holding only :data:`START_FILES` (a run stopped before its first checkpoint) is started
over at step 0, with or without ``--resume``; one with a checkpoint needs ``--resume``; anything
else is refused. **Determinism**: :func:`deterministic` (Dr.Jit on one thread, deterministic
CUDA kernels) around the run; same seed, machine, torch thread count and world size give the
same bits. Only rank 0 prints.

**Structure.** Each phase is a small object of :mod:`.phases` (its inputs, cache and forward are
constructor arguments; its loss one method); the caches are a :class:`.cache.RunCaches`, filled
when a phase first needs them; a resume hands its :class:`ResumePoint` to the phase it continues.
The trainer owns the loop: optimiser, learning rate, sample order, logging and checkpoints.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import InputError
from ..fsutil import OutputLock, atomic_write_text, is_temporary, remove_stale_temporaries
from ..model.bundle import DataFacts, build_bundle, net_configs
from ..model.checkpoint import load_checkpoint, save_checkpoint
from ..model.config import PHASES, TrainConfig
from ..model.device import pick_device
from ..nets.losses import MapWeights
from . import ddp
from .cache import RunCaches
from .data import CAPTURE_SHOTS, load_training_data
from .phases import Phase, PhaseInputs, PhasePlan, build_phase, plan_phases

CSV_FIELDS = ("phase", "step", "loss", "terms", "lr", "samples_per_s", "seconds")
START_FILES = frozenset({"config.json", "log.csv", "cache"})
"""What a run writes before its first checkpoint: a directory holding only these is started over."""


def cosine_lr(step: int, total: int, lr0: float, lr1: float) -> float:
    """Cosine decay from ``lr0`` (step 0) to ``lr1`` (step ``total``)."""
    if total <= 1:
        return lr0
    return lr1 + 0.5 * (lr0 - lr1) * (1.0 + math.cos(math.pi * min(step, total) / total))


@contextlib.contextmanager
def deterministic(cuda: bool = False):
    """Same-seed runs give the same bits on one machine: for the block, Dr.Jit runs on one thread
    (its multi-threaded scatter-adds — the SG extraction of the stage-2 cache, the gradients of the
    Dr.Jit renders — add in a varying order otherwise), and with ``cuda`` cuDNN/torch pick
    deterministic kernels. torch's CPU kernels are deterministic for a fixed thread count already.
    Everything is restored afterwards."""
    import drjit as dr

    threads = dr.thread_count()
    cudnn = (torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark)
    algorithms = (
        torch.are_deterministic_algorithms_enabled(),
        torch.is_deterministic_algorithms_warn_only_enabled(),
    )
    dr.set_thread_count(1)
    torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False
    if cuda:
        torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        dr.set_thread_count(threads)
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = cudnn
        torch.use_deterministic_algorithms(algorithms[0], warn_only=algorithms[1])


@dataclass(frozen=True)
class ResumePoint:
    """Where ``--resume`` continues inside a phase: the checkpoint's phase, step (the next step
    to run), the phase's elapsed seconds, optimizer state and generator states, and the sample
    order ``(permutation, position)`` (None in a checkpoint of an older version)."""

    phase: str
    step: int
    seconds: float
    optimizer: dict
    rng: dict
    order: tuple[torch.Tensor, int] | None

    @classmethod
    def from_checkpoint(cls, data: dict) -> ResumePoint:
        step, rng = data["step"], data["rng"]
        return cls(
            step["phase"],
            int(step["step"]),
            float(step.get("seconds", 0.0)),
            data["optimizer"],
            rng,
            (rng["perm"], rng["pos"]) if "perm" in rng else None,
        )


class Trainer:
    """One training run (see the module docstring). ``log(msg)`` prints human messages;
    ``progress`` is a tqdm-like factory (None: no bars)."""

    def __init__(
        self, config: TrainConfig, out: str | Path, *, resume: bool = False, log=None, progress=None
    ):
        self.config = config
        self.out = Path(out)
        self.resume = resume
        self.progress = progress
        self.device = ddp.local_device(pick_device(config.train.device))
        if self.device.type == "cuda":  # before the first cuBLAS call (deterministic GEMMs)
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        self.dist = ddp.init_distributed(self.device)
        self.log = (log or (lambda msg: None)) if self.dist.main else (lambda msg: None)  # rank 0 speaks
        # rank 0 holds the lock of --out for the run: a second run into it is refused (BusyError)
        self._lock = OutputLock(self.out, "ebr train").acquire() if self.dist.main else None
        try:
            self._setup()
        except BaseException:
            self.close()
            raise

    def _setup(self) -> None:
        config = self.config
        if config.train.threads > 0:
            torch.set_num_threads(config.train.threads)
        torch.set_flush_denormal(True)  # NAFNet's zero-initialised scales otherwise meet denormals
        self.facts = DataFacts.from_dataset(config.data.train)
        self._check_setup()
        torch.manual_seed(config.train.seed)
        self.bundle = build_bundle(config, self.facts, self.device)
        self.data = load_training_data(
            config.data.train, config.data.max_samples, self.progress if self.dist.main else None
        )
        self.state = {"phase": None, "step": 0, "done": [], "seconds": 0.0}
        self._resume: ResumePoint | None = None  # set by _load_resume, handed to its phase
        self.summary: dict = {"phases": {}}
        self._prepare_out()
        self.inputs = PhaseInputs(
            self.data,
            self.device,
            self.capture,
            self.facts.flash_intensity,
            MapWeights()
            if config.kind == "mair"  # MAIR weighs its own terms (MAIRLossConfig)
            else MapWeights(
                config.loss.normal, config.loss.diffuse, config.loss.specular, config.loss.roughness
            ),
            config.loss,
        )
        bar = self.progress if self.dist.main else None
        self.caches = RunCaches(self.out, self.data, config, self.dist, bar)

    def close(self) -> None:
        """Release the lock of ``--out`` and turn torch's denormal flushing (process-wide, set by
        the set-up) back off, its default, so that code after a run (``ebr train`` in a test, a
        notebook) computes with denormals again (also done when :meth:`run` ends or fails)."""
        torch.set_flush_denormal(False)
        if self._lock is not None:
            self._lock.release()

    # -- setup --------------------------------------------------------------------------------

    @property
    def capture(self) -> str:
        """``near`` or ``near-far`` (ebrenv; the ``[model].capture`` of the config)."""
        return self.config.model.get("capture", "near")

    def _check_setup(self) -> None:
        have, data = self.facts.setup, self.config.data.train
        if self.config.kind == "dualloss":
            if have != "five-light":
                raise InputError(
                    f"{data}: a '{have}' data set; a dualloss config needs a 'five-light' one "
                    f"(ebr generate with [capture] setup = 'five-light')"
                )
            return
        if self.config.kind == "mair":
            self._check_multiview(have, data)
            return
        want = self.capture
        if have != want:
            fix = (
                f"set [model].capture = '{have}' in {self.config.source} or " if have in CAPTURE_SHOTS else ""
            )
            raise InputError(
                f"{data}: a '{have}' data set; {self.config.source} has [model].capture = '{want}' "
                f"and needs a '{want}' one ({fix}generate one with [capture] setup = '{want}')"
            )

    def _check_multiview(self, have: str, data: str) -> None:
        """A mair config needs a multi-view data set whose views lie on the sample grid (the fast
        renderer's texture-space renders); Mitsuba's are camera images, not rectified yet."""
        if have != "multi-view":
            raise InputError(
                f"{data}: a '{have}' data set; a mair config needs a 'multi-view' one "
                f"(ebr generate with [capture] setup = 'multi-view', e.g. configs/data_tiny_multiview.toml)"
            )
        from ..data import store

        doc = store.read_doc(Path(data) / store.DATASET_JSON, store.DATASET_FORMAT, "regenerate it")
        renderer = (doc.get("renderer") or {}).get("name")
        if renderer != "fast":
            raise InputError(
                f"{data}: multi-view views rendered by '{renderer}' are camera images; MAIR training "
                f"takes texture-space views on the sample grid: generate with [render] renderer = 'fast'"
            )

    def _prepare_out(self) -> None:
        """Check ``--out`` and set up the start or the resume (module docstring, "Output")."""
        last = self.out / "last.pt"
        names = [p.name for p in self.out.iterdir()] if self.out.exists() else []
        others = sorted(n for n in names if n not in START_FILES and not is_temporary(n))
        if self.resume and last.is_file():
            self._load_resume(last)
        elif others and self.dist.main:
            if self.resume:
                raise InputError(f"{last}: nothing to resume; run without --resume first")
            fix = "pass --resume to continue the run there" if last.is_file() else "remove it"
            raise InputError(f"--out {self.out}: exists and is not empty; {fix} or choose a new directory")
        else:  # a new run, or one killed before its first checkpoint: start (over) at step 0
            old = self._old_config()
            if old is not None and old != json.loads(json.dumps(self.config.to_dict())):
                if self.resume:
                    raise InputError(
                        f"{self.out / 'config.json'}: written with another config; resume with the same "
                        f"config or choose a new --out"
                    )
                if self.dist.main:  # another config's exemplar selections and SGs
                    shutil.rmtree(self.out / "cache", ignore_errors=True)
            if self.resume:
                self.log(f"{self.out}: no checkpoint yet (stopped before the first one): starting at step 0")
            if self.config.train.init:
                data = load_checkpoint(self.config.train.init, expect_kind=self.config.kind)
                state, nets = data["model"], self.config.train.init_nets
                if nets:
                    missing = [n for n in nets if n not in state]
                    if missing:
                        raise InputError(
                            f"{self.config.train.init}: has no {', '.join(missing)} weights "
                            f"(it holds {', '.join(state)}); fix [train].init_nets"
                        )
                    state = {n: state[n] for n in nets}
                self.bundle.load_state(state, self.config.train.init, strict=False)
                self.log(f"initialised from {self.config.train.init} ({', '.join(state)})")
        ddp.barrier(self.dist)
        if self.dist.main:
            self.out.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.out)  # what killed atomic writes left (we hold the lock)
            atomic_write_text(self.out / "config.json", json.dumps(self.config.to_dict(), indent=1) + "\n")
            self._write_log_rows(self._kept_log_rows() if self._resume is not None else [])
        ddp.barrier(self.dist)

    def _old_config(self) -> dict | None:
        path = self.out / "config.json"
        try:
            return json.loads(path.read_text()) if path.is_file() else None
        except (OSError, ValueError):
            return None  # damaged: the run is started over and rewrites it

    def _load_resume(self, last: Path) -> None:
        data = load_checkpoint(last, expect_kind=self.config.kind)
        if data["config"] != self.config.to_dict():
            raise InputError(
                f"{last}: written with another config; resume with the same config or choose a new --out"
            )
        self.bundle.load_state(data["model"], str(last))
        self.state = {"seconds": 0.0, **data["step"]}
        self._resume = ResumePoint.from_checkpoint(data)
        if isinstance(data.get("summary"), dict):  # the phases finished before the checkpoint
            self.summary = data["summary"]
        else:  # a checkpoint of an older version: the phases of a finished run's summary.json
            old = self.out / "summary.json"
            try:
                self.summary["phases"].update(json.loads(old.read_text()).get("phases", {}))
            except (OSError, ValueError, AttributeError):
                pass
        self.log(f"resuming at phase {self.state['phase']} step {self.state['step']}")

    def _kept_log_rows(self) -> list[list[str]]:
        """The rows of ``log.csv`` up to the checkpoint resumed from (later ones are redone)."""
        path = self.out / "log.csv"
        if not path.is_file():
            return []
        with open(path, newline="") as f:
            rows = list(csv.reader(f))[1:]
        done, phase, step = set(self.state.get("done", [])), self.state.get("phase"), int(self.state["step"])
        kept = []
        for row in rows:
            try:
                ok = row[0] in done or (row[0] == phase and int(row[1]) <= step)
            except (IndexError, ValueError):
                ok = False  # a line cut short by the kill
            if ok:
                kept.append(row)
        return kept

    def _write_log_rows(self, rows: list[list[str]]) -> None:
        import io

        buf = io.StringIO()
        writer = csv.writer(buf)
        writer.writerow(CSV_FIELDS)
        writer.writerows(rows)
        atomic_write_text(self.out / "log.csv", buf.getvalue())

    # -- phases -------------------------------------------------------------------------------

    def phases(self) -> list[PhasePlan]:
        """The run's phases in order (:func:`.phases.plan_phases`); phases with nothing to train dropped."""
        return plan_phases(self.config, self.bundle)

    def phase(self, name: str) -> Phase:
        """The phase ``name`` of this run, built with its inputs; a cascade phase fills (this
        rank's share) and loads its cache first if no phase did yet."""
        plan = next((p for p in self.phases() if p.name == name), None)
        if plan is None:
            names = ", ".join(p.name for p in self.phases())
            raise ValueError(f"Trainer.phase: no phase {name!r} in this run; it has {names}")
        return build_phase(plan, self.inputs, self.bundle, self.caches)

    def run(self) -> dict:
        """Train every phase not done yet, write ``model.pt`` and ``summary.json``; returns the
        summary. Releases the lock of ``--out`` when it ends, however it ends."""
        try:
            with deterministic(self.device.type == "cuda"):
                return self._run()
        finally:
            self.close()

    def _run(self) -> dict:
        t_start = time.perf_counter()
        for index, plan in enumerate(self.phases()):
            if plan.name in self.state.get("done", []):
                continue
            phase = self.phase(plan.name)
            resume, self._resume = self._resume, None  # only the first phase run can continue it
            if resume is not None and resume.phase != plan.name:
                resume = None  # the checkpoint ended its phase: this one starts at step 0
            self._run_phase(index, phase, resume)
        if self.dist.main:
            self._save(self.out / "model.pt")
            # training time summed over the phases, so a resumed (or re-exported) run keeps its total
            phase_seconds = sum(p.get("seconds", 0.0) for p in self.summary["phases"].values())
            self.summary["seconds"] = round(max(phase_seconds, time.perf_counter() - t_start), 1)
            self.summary["samples"] = len(self.data)
            self.summary["device"] = str(self.device)
            self.summary["world_size"] = self.dist.world
            atomic_write_text(self.out / "summary.json", json.dumps(self.summary, indent=1) + "\n")
        ddp.barrier(self.dist)
        return self.summary

    def _freeze(self, modules) -> None:
        for net in self.bundle.nets().values():
            net.requires_grad_(False)
            net.train(False)
        for m in modules:
            m.requires_grad_(True)
            m.train(True)

    def _run_phase(self, index: int, phase: Phase, resume: ResumePoint | None) -> None:
        """Train ``phase`` (the ``index``-th of the run: seeds its generators) from step 0, or
        from ``resume`` (a checkpoint inside this phase)."""
        t = self.config.train
        name, steps = phase.name, phase.steps
        self._freeze(phase.modules)
        params = [p for m in phase.modules for p in m.parameters()]
        opt = torch.optim.Adam(params, lr=phase.lr, weight_decay=t.weight_decay)
        order_gen = torch.Generator().manual_seed(t.seed * 1000 + index)
        loss_gen = torch.Generator().manual_seed(t.seed * 1000 + 500 + index)
        start = 0
        if resume is not None:
            start = resume.step
            opt.load_state_dict(resume.optimizer)
            order_gen.set_state(resume.rng["order"])
            loss_gen.set_state(resume.rng["loss"])
        model = ddp.wrap(phase.top, self.dist, self.device)
        n_data = phase.size
        batch = min(t.batch_size, n_data)
        if start > 0 and resume.order is not None:
            perm, pos = resume.order
        else:
            perm, pos = torch.randperm(n_data, generator=order_gen), 0
        bar = (
            self.progress(total=steps, initial=start, desc=name, unit="step")
            if (self.progress and self.dist.main)
            else None
        )
        elapsed = resume.seconds if start > 0 else 0.0  # before the resume
        t0 = time.perf_counter() - elapsed
        seen, last_log = 0, time.perf_counter()
        loss_value, terms = float("nan"), {}
        for step in range(start, steps):
            lr = cosine_lr(step, steps, phase.lr, t.lr_final)
            for g in opt.param_groups:
                g["lr"] = lr
            if pos + batch * self.dist.world > n_data:
                perm, pos = torch.randperm(n_data, generator=order_gen), 0
            chunk = perm[pos : pos + batch * self.dist.world]
            pos += batch * self.dist.world
            idx = chunk[self.dist.rank :: self.dist.world]
            loss, parts = self._loss(phase, model, idx, loss_gen)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            seen += len(idx) * self.dist.world
            done = step + 1
            if done % t.log_every == 0 or done == steps:
                loss_value = ddp.all_mean(float(loss.detach()), self.dist)
                terms = {k: round(ddp.all_mean(float(v.detach()), self.dist), 6) for k, v in parts.items()}
                now = time.perf_counter()
                rate = seen / max(now - last_log, 1e-9)
                seen, last_log = 0, now
                if self.dist.main:
                    with open(self.out / "log.csv", "a", newline="") as f:
                        csv.writer(f).writerow(
                            [
                                name,
                                done,
                                f"{loss_value:.6g}",
                                json.dumps(terms),
                                f"{lr:.3g}",
                                f"{rate:.2f}",
                                f"{now - t0:.1f}",
                            ]
                        )
                if bar is not None:
                    bar.n = done
                    bar.set_postfix_str(f"loss {loss_value:.4g}, {rate:.1f} samples/s")
                    bar.refresh()
            if done == steps:  # before the checkpoint, which carries the summary to a resume
                self.summary["phases"][name] = {
                    "steps": steps,
                    "final_loss": loss_value,
                    "terms": terms,
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            if done % t.checkpoint_every == 0 or done == steps:
                self.state = {
                    "phase": name,
                    "step": done,
                    "done": list(self.state.get("done", [])) + ([name] if done == steps else []),
                    "seconds": round(time.perf_counter() - t0, 3),
                }
                if self.dist.main:
                    self._save(self.out / "last.pt", opt, order_gen, loss_gen, (perm, pos))
                    if done == steps:
                        self._save(self.out / f"after_{name}.pt")
        if bar is not None:
            bar.close()
        self.log(f"{name}: {steps} steps, loss {loss_value:.4g} ({time.perf_counter() - t0:.0f} s)")

    def _save(self, path: Path, opt=None, order_gen=None, loss_gen=None, order=None) -> None:
        """Checkpoint to ``path``; ``order`` = (permutation, position) of the sample order."""
        payload = {
            "kind": self.config.kind,
            "config": self.config.to_dict(),
            "model": self.bundle.state(),
            "net_config": net_configs(self.bundle),
            "data": self.facts.to_dict(),
            "step": self.state,
            "summary": self.summary,
            "optimizer": opt.state_dict() if opt is not None else None,
            "rng": {
                "order": order_gen.get_state(),
                "loss": loss_gen.get_state(),
                "perm": order[0].clone(),
                "pos": int(order[1]),
            }
            if order_gen is not None
            else None,
        }
        save_checkpoint(path, payload)

    def _loss(self, phase: Phase, model, idx: torch.Tensor, gen: torch.Generator):
        """One step's loss and per-term values (:meth:`.phases.Phase.loss`)."""
        return phase.loss(model, idx, gen)


__all__ = ["PHASES", "ResumePoint", "Trainer", "cosine_lr"]
