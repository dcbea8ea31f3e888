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
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import time
from pathlib import Path

import torch

from ..errors import InputError
from ..fsutil import OutputLock, atomic_write_text, is_temporary, remove_stale_temporaries
from ..nets import Maps
from ..nets.losses import MapWeights, parameter_l1, rendering_loss, sample_view_light_pairs
from ..nets.transforms import log_input
from . import cache, ddp
from .bundle import DataFacts, build_bundle, net_configs
from .checkpoint import load_checkpoint, save_checkpoint
from .config import PHASES, TrainConfig
from .data import CAPTURE_SHOTS, load_training_data
from .inference import pick_device
from .renders import cascade_forward

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


@contextlib.contextmanager
def _first_stage_only(cascade):
    """Run the cascade without its refinement net (phases that train the first stage)."""
    saved = cascade.refinement_net
    cascade.refinement_net = None
    try:
        yield
    finally:
        cascade.refinement_net = saved


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
        self.resume_data = None
        self._resume_order = None
        self.summary: dict = {"phases": {}}
        self._prepare_out()
        self.weights = MapWeights(
            config.loss.normal, config.loss.diffuse, config.loss.specular, config.loss.roughness
        )

    def close(self) -> None:
        """Release the lock of ``--out`` (also done when :meth:`run` ends or fails)."""
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
        want = self.capture
        if have != want:
            fix = (
                f"set [model].capture = '{have}' in {self.config.source} or " if have in CAPTURE_SHOTS else ""
            )
            raise InputError(
                f"{data}: a '{have}' data set; {self.config.source} has [model].capture = '{want}' "
                f"and needs a '{want}' one ({fix}generate one with [capture] setup = '{want}')"
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
                self.bundle.load_state(data["model"], self.config.train.init, strict=False)
                self.log(f"initialised from {self.config.train.init}")
        ddp.barrier(self.dist)
        if self.dist.main:
            self.out.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.out)  # what killed atomic writes left (we hold the lock)
            atomic_write_text(self.out / "config.json", json.dumps(self.config.to_dict(), indent=1) + "\n")
            self._write_log_rows(self._kept_log_rows() if self.resume_data is not None else [])
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
        self.resume_data = data
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

    def phases(self) -> list[tuple[str, int, list[torch.nn.Module], float]]:
        """(name, steps, trainable modules, initial lr) in order; phases with nothing to train dropped."""
        c, t = self.config, self.config.train
        if c.kind == "dualloss":
            return [("dualloss", t.steps, [self.bundle.dualloss], t.lr)]
        cas = self.bundle.cascade
        out = [("lighting", c.stages.lighting, [self.bundle.lighting], t.lr)]
        if cas.joint_net is not None:
            out.append(("diffuse", c.stages.diffuse, [cas.joint_net], t.lr))
        else:
            out += [
                ("diffuse", c.stages.diffuse, [cas.diffuse_net], t.lr),
                ("specular", c.stages.specular, [cas.specular_net], t.lr),
            ]
        if cas.refinement_net is not None:
            out.append(("refinement", c.stages.refinement, [cas.refinement_net], t.lr))
        if c.stages.finetune > 0 and c.stages.finetune_samples > 0:
            out.append(("finetune", c.stages.finetune, [cas], c.stages.finetune_lr))
        return [p for p in out if p[1] > 0]

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
        for index, (name, steps, modules, lr0) in enumerate(self.phases()):
            if name in self.state.get("done", []):
                continue
            self._prepare_phase(name)
            self._run_phase(index, name, steps, modules, lr0)
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

    def _my_indices(self, indices) -> list[int]:
        return [i for k, i in enumerate(indices) if k % self.dist.world == self.dist.rank]

    def _prepare_phase(self, name: str) -> None:
        c = self.config
        if c.kind != "ebrenv" or name == "lighting":
            return
        n = len(self.data)
        bar = self.progress if self.dist.main else None
        if name in ("diffuse", "specular", "refinement"):
            if not hasattr(self, "stage1") and c.cascade_config().use_exemplars:
                cache.fill_stage1(self.out, self.data, self._my_indices(range(n)), c.select_config(), bar)
                ddp.barrier(self.dist)
                self.stage1 = cache.load_cache(self.out, "stage1", range(n))
        elif name == "finetune":
            m = min(n, c.stages.finetune_samples)
            self.bundle.train(False)
            cache.fill_stage2(
                self.out,
                self.data,
                self._my_indices(range(m)),
                self.bundle,
                c.select_config(),
                c.extract_config(),
                bar,
            )
            ddp.barrier(self.dist)
            self.stage2 = cache.load_cache(self.out, "stage2", range(m))

    def _freeze(self, modules) -> None:
        for net in self.bundle.nets().values():
            net.requires_grad_(False)
            net.train(False)
        for m in modules:
            m.requires_grad_(True)
            m.train(True)

    def _run_phase(self, index: int, name: str, steps: int, modules, lr0: float) -> None:
        t = self.config.train
        self._freeze(modules)
        params = [p for m in modules for p in m.parameters()]
        opt = torch.optim.Adam(params, lr=lr0, weight_decay=t.weight_decay)
        order_gen = torch.Generator().manual_seed(t.seed * 1000 + index)
        loss_gen = torch.Generator().manual_seed(t.seed * 1000 + 500 + index)
        start = 0
        if self.resume_data is not None and self.state.get("phase") == name:
            start = int(self.state["step"])
            opt.load_state_dict(self.resume_data["optimizer"])
            order_gen.set_state(self.resume_data["rng"]["order"])
            loss_gen.set_state(self.resume_data["rng"]["loss"])
            rng = self.resume_data["rng"]
            self._resume_order = (rng["perm"], rng["pos"]) if "perm" in rng else None
        self.resume_data = None
        top = (
            self.bundle.lighting
            if name == "lighting"
            else (self.bundle.dualloss if name == "dualloss" else self.bundle.cascade)
        )
        model = ddp.wrap(top, self.dist, self.device)
        n_data = len(self.stage2["flash_only"]) if name == "finetune" else len(self.data)
        batch = min(t.batch_size, n_data)
        if start > 0 and self._resume_order is not None:
            perm, pos = self._resume_order
        else:
            perm, pos = torch.randperm(n_data, generator=order_gen), 0
        bar = (
            self.progress(total=steps, initial=start, desc=name, unit="step")
            if (self.progress and self.dist.main)
            else None
        )
        elapsed = float(self.state.get("seconds", 0.0)) if start > 0 else 0.0  # before the resume
        t0 = time.perf_counter() - elapsed
        seen, last_log = 0, time.perf_counter()
        loss_value, terms = float("nan"), {}
        for step in range(start, steps):
            lr = cosine_lr(step, steps, lr0, t.lr_final)
            for g in opt.param_groups:
                g["lr"] = lr
            if pos + batch * self.dist.world > n_data:
                perm, pos = torch.randperm(n_data, generator=order_gen), 0
            chunk = perm[pos : pos + batch * self.dist.world]
            pos += batch * self.dist.world
            idx = chunk[self.dist.rank :: self.dist.world]
            loss, parts = self._loss(name, model, idx, loss_gen)
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

    # -- losses -------------------------------------------------------------------------------

    def _target(self, idx) -> Maps:
        return Maps.unstack(self.data.maps[idx].to(self.device))

    def _loss(self, name: str, model, idx: torch.Tensor, gen: torch.Generator):
        d, dev = self.data, self.device
        if name == "lighting":
            out = model(d.shots(idx, CAPTURE_SHOTS[self.capture]).to(dev))
            ex = (log_input(out.exemplars) - log_input(d.env_exemplars[idx].to(dev))).abs().mean()
            fo = (log_input(out.flash_only) - log_input(d.flash_only_of(idx).to(dev))).abs().mean()
            return ex + fo, {"exemplars": ex, "flash_only": fo}
        target = self._target(idx)
        if name == "dualloss":
            pred = model(d.photos[idx].to(dev))
            loss, parts = parameter_l1(pred, target, self.weights)
            if self.config.loss.render > 0:
                from ..nets.drwrap import point_light_renderer

                pairs = sample_view_light_pairs(
                    len(idx),
                    gen,
                    self.config.loss.render_pairs,
                    self.config.loss.render_highlights,
                    device=dev,
                )
                r = rendering_loss(pred, target, pairs, point_light_renderer(self.facts.flash_intensity))
                loss, parts = loss + self.config.loss.render * r, {**parts, "render": r}
            return loss, parts
        out = self._cascade(name, model, idx)
        if name in ("diffuse", "specular"):
            m, joint = out.coarse, self.bundle.cascade.joint_net is not None
            keys = (
                ("normal", "diffuse", "specular", "roughness")
                if joint
                else (("normal", "diffuse") if name == "diffuse" else ("specular", "roughness"))
            )
            parts = {k: (getattr(m, k) - getattr(target, k)).abs().mean() for k in keys}
            return sum(getattr(self.weights, k) * v for k, v in parts.items()), parts
        loss, parts = parameter_l1(out.maps, target, self.weights)
        if name == "finetune":
            coarse, _ = parameter_l1(out.coarse, target, self.weights)
            loss, parts = loss + coarse, {**parts, "coarse": coarse}
        if self.config.loss.render > 0:
            from ..nets import torch_brdf as tb

            pairs = sample_view_light_pairs(
                len(idx), gen, self.config.loss.render_pairs, self.config.loss.render_highlights, device=dev
            )
            r = rendering_loss(
                out.maps,
                target,
                pairs,
                lambda m, cam, light: tb.render_point_light(m, light, self.facts.flash_intensity, cam),
            )
            loss, parts = loss + self.config.loss.render * r, {**parts, "render": r}
        return loss, parts

    def _cascade(self, name: str, model, idx: torch.Tensor):
        d, dev = self.data, self.device
        noflash = d.photos[idx, d.shot("noflash")].to(dev)
        photos = d.shots(idx, CAPTURE_SHOTS[self.capture]).to(dev)
        far_fo = d.far_flash_only(idx).to(dev) if self.capture == "near-far" else None
        if name == "finetune":
            src = self.stage2
            flash_only = src["flash_only"][idx].to(dev)
            lobes = [src["sg"][int(i)].to(dev) for i in idx]
        else:
            src = getattr(self, "stage1", None)
            flash_only = d.flash_only_of(idx).to(dev)
            lobes = [lb.to(dev) for lb in d.lobes(idx)]
        env_ex = src["env_images"][idx].to(dev) if src is not None and "env_images" in src else None
        point_ex = src["point_images"][idx].to(dev) if src is not None and "point_images" in src else None
        ctx = (
            _first_stage_only(self.bundle.cascade)
            if name in ("diffuse", "specular")
            else contextlib.nullcontext()
        )
        with ctx:
            return cascade_forward(
                model,
                noflash,
                flash_only,
                env_ex,
                point_ex,
                photos,
                lobes,
                self.facts.flash_intensity,
                far_fo,
            )


__all__ = ["PHASES", "Trainer", "cosine_lr"]
