"""Stage ``baseline train``: fit the stereo baseline on a sequence's adaptation split.

:func:`train_step` is the pure part (forward, loss, optimiser step); :func:`train` is the loop that
owns data, checkpoints (atomic: temporary file + ``os.replace``), resuming, progress and logging.
Randomness is derived from ``conf.seed`` and the epoch / step number, so a resumed run follows the
same batches and augmentations as an uninterrupted one (bit-exact on the CPU).
"""
from __future__ import annotations

import os
import time
from typing import Any, Callable, Mapping

import torch

from staticdepth.baseline.config import BaselineConfig, config_from_dict
from staticdepth.baseline.data import StereoGeometry, load_pairs, sample_batch, stereo_geometry
from staticdepth.baseline.losses import stereo_loss
from staticdepth.baseline.network import DepthNet, build_model
from staticdepth.errors import InputError
from staticdepth.progress import progress

CHECKPOINT_FORMAT = "staticdepth.baseline/1"
_SEED_STRIDE = 1_000_003


def train_step(model: DepthNet, batch: Mapping[str, torch.Tensor], conf: BaselineConfig,
               optimizer: torch.optim.Optimizer | None = None) -> dict[str, float]:
    """One step on a batch from :func:`~staticdepth.baseline.data.make_batch` (on the model's
    device). Computes the loss; with an ``optimizer``, also back-propagates and steps.
    Returns the loss terms as floats."""
    disps = model(batch["image"])
    terms = stereo_loss(disps, batch["target"], batch["source"], batch["focal_px"],
                        batch["baseline_m"], batch["direction"], conf)
    if optimizer is not None:
        optimizer.zero_grad(set_to_none=True)
        terms["loss"].backward()
        optimizer.step()
    return {k: float(v.detach()) for k, v in terms.items()}


def default_checkpoint_path(sequence_path: str | os.PathLike) -> str:
    base = os.fspath(sequence_path)
    if base.endswith(".h5"):
        base = base[:-3]
    return base + ".baseline.pt"


def save_checkpoint(path: str, state: dict[str, Any]) -> None:
    """Write ``state`` with ``torch.save`` atomically."""
    from staticdepth.fileio import atomic_torch_save

    atomic_torch_save(path, state, "ckpt")


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a baseline checkpoint (tensors and plain values only); errors name the file.

    :func:`save_checkpoint` writes torch's zip format: a file that is no zip archive (truncated,
    empty, another format) is refused in one line before torch reads it."""
    import zipfile

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("checkpoint not found (train first: staticdepth baseline train)", path)
    if not zipfile.is_zipfile(path):
        raise InputError("not a readable checkpoint (truncated or not a torch file)", path)
    from staticdepth.models.trust import torch_load
    try:
        state = torch_load(path, what="checkpoint")  # tensors and plain values only
    except InputError as e:
        if not e.problem.startswith("not a readable"):
            raise                                  # e.g. a file that would run code
        raise InputError("not a readable checkpoint (a damaged torch file or another zip "
                         "archive)", path) from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"not a stereo-baseline checkpoint (expected format "
                         f"{CHECKPOINT_FORMAT!r})", path)
    state["config"] = config_from_dict(state["config"], path)
    return state


def check_checkpoint_path(checkpoint_path: str | os.PathLike,
                          inputs: Mapping[str, str | os.PathLike | None]) -> None:
    """Refuse a checkpoint (written by training) that names one of the command's ``inputs``
    (role -> path; the sequence, the ImageNet weights), through links and relative paths, even
    with ``--overwrite``: the checkpoint would replace the input."""
    ckpt = os.fspath(checkpoint_path)
    for role, path in inputs.items():
        if path and _same_file(ckpt, os.fspath(path)):
            raise InputError(f"--checkpoint names this command's input ({role}): writing it would "
                             "destroy the input; choose another --checkpoint", ckpt)


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:                                # one of them does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def check_checkpoint_every(steps: int) -> None:
    """Refuse a checkpoint interval below one optimisation step (0 has no meaning)."""
    if isinstance(steps, bool) or not (isinstance(steps, int) and steps >= 1):
        raise InputError(f"--checkpoint-every must be >= 1 (optimisation steps), got {steps!r}")


def _samples_per_epoch(n_frames: int, conf: BaselineConfig) -> int:
    return n_frames * (2 if conf.both_sides else 1)


def train(sequence_path: str | os.PathLike, checkpoint_path: str | os.PathLike,
          conf: BaselineConfig, device: torch.device | str = "cpu", *, overwrite: bool = False,
          checkpoint_every: int = 200, log: Callable[[str], None] | None = None
          ) -> dict[str, Any]:
    """Train on the adaptation split of ``sequence_path``; checkpoint to ``checkpoint_path``.

    An existing unfinished checkpoint with the same settings is resumed; a finished one is kept
    (nothing to do) unless ``overwrite``; one with other settings is an error. Checkpoints are
    written every ``checkpoint_every`` (>= 1) steps and at the end of every epoch; ``log`` lines
    are printed above the progress bar.
    The checkpoint records the sequence's identity (``SequenceReader.sequence_id``); one trained
    on another sequence (the file replaced since) is refused unless ``overwrite``. A checkpoint
    that names the sequence or the ImageNet weights is refused even with ``overwrite``.
    Returns a summary: epochs, steps, per-epoch mean losses, seconds, images per second, and
    ``already_trained`` (a finished checkpoint kept: the summary is of that earlier training).
    """
    from staticdepth.dataset.h5 import SequenceReader

    check_checkpoint_every(checkpoint_every)
    log = log or (lambda s: None)
    seq, ckpt = os.fspath(sequence_path), os.fspath(checkpoint_path)
    check_checkpoint_path(ckpt, {"sequence": seq, "imagenet weights": conf.imagenet_weights})
    device = torch.device(device)
    resume = os.path.exists(ckpt) and not overwrite
    with SequenceReader(seq) as r:
        geo = stereo_geometry(r, conf)
        seq_name, seq_id = r.meta.name, r.sequence_id()
        state = load_checkpoint(ckpt) if resume else None
        if state is not None:                     # refused before the frames are read
            _check_compatible(state, conf, geo, ckpt, seq, seq_id, log)
        left, right = load_pairs(r, r.split("adapt"), conf)
    torch.manual_seed(conf.seed)
    model = build_model(conf, load_weights=not resume).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=conf.lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, conf.lr_step_epochs, conf.lr_gamma)
    epoch, batch0, step, history = 0, 0, 0, []
    already_trained = state is not None and state["epoch"] >= conf.epochs
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        epoch, batch0, step = state["epoch"], state["batch"], state["step"]
        history = list(state["history"])
        log(f"resuming {ckpt} at epoch {epoch}, step {step}" if epoch < conf.epochs
            else f"{ckpt} is already trained ({conf.epochs} epochs); --overwrite to retrain")
    n_samples = _samples_per_epoch(len(left), conf)
    per_epoch = max(1, n_samples // conf.batch_size)   # drop_last, as MonoDepth2
    bs = min(conf.batch_size, n_samples)

    def snapshot(done_batches: int) -> dict[str, Any]:
        e, b = (epoch + 1, 0) if done_batches == per_epoch else (epoch, done_batches)
        return {"format": CHECKPOINT_FORMAT, "config": conf.to_dict(), "model": model.state_dict(),
                "optimizer": opt.state_dict(), "scheduler": sched.state_dict(), "epoch": e,
                "batch": b, "step": step, "history": history, "sequence": seq_name,
                "sequence_id": seq_id,
                "baseline_m": geo.baseline_m, "focal_px": geo.focal_px,
                "focal_px_full": geo.focal_px_full, "sequence_size": list(geo.sequence_size)}

    t0, n_images = time.perf_counter(), 0
    model.train()
    bar = progress(total=(conf.epochs - epoch) * per_epoch - batch0, desc="baseline train",
                   unit="step")
    while epoch < conf.epochs:
        perm = torch.randperm(n_samples, generator=torch.Generator().manual_seed(
            conf.seed * _SEED_STRIDE + epoch))
        losses = [h for h in history if h["epoch"] == epoch]
        for b in range(batch0, per_epoch):
            g = torch.Generator().manual_seed(conf.seed * _SEED_STRIDE + 7919 * (step + 1))
            torch.manual_seed(conf.seed * _SEED_STRIDE + 104729 * (step + 1))
            batch = sample_batch(left, right, perm[b * bs:(b + 1) * bs], geo, conf, g)
            batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
            terms = train_step(model, batch, conf, opt)
            step += 1
            n_images += bs
            rec = {"epoch": epoch, "step": step, **terms}
            history.append(rec)
            losses.append(rec)
            bar.update(1)
            bar.set_postfix(loss=f"{terms['loss']:.4f}", epoch=epoch)
            if step % checkpoint_every == 0 and b + 1 < per_epoch:
                save_checkpoint(ckpt, snapshot(b + 1))
        lr = opt.param_groups[0]["lr"]
        sched.step()
        save_checkpoint(ckpt, snapshot(per_epoch))
        mean = sum(h["loss"] for h in losses) / max(1, len(losses))
        with bar.external_write_mode():     # tqdm's own: clear the bar, print, redraw it
            log(f"epoch {epoch + 1}/{conf.epochs}: loss {mean:.4f} (lr {lr:.2e})")
        epoch, batch0 = epoch + 1, 0
    bar.close()
    seconds = time.perf_counter() - t0
    collapse = _self_check(model, left, conf, device, ckpt)
    epochs = sorted({h["epoch"] for h in history})
    epoch_loss = [sum(h["loss"] for h in history if h["epoch"] == e)
                  / sum(1 for h in history if h["epoch"] == e) for e in epochs]
    return {"checkpoint": ckpt, "epochs": conf.epochs, "steps": step, "epoch_loss": epoch_loss,
            "seconds": seconds, "images_per_s": n_images / seconds if n_images else 0.0,
            "frames": len(left), "baseline_m": geo.baseline_m, "focal_px": geo.focal_px,
            "self_check": collapse, "already_trained": already_trained}


@torch.no_grad()
def _self_check(model: DepthNet, left: torch.Tensor, conf: BaselineConfig, device,
                ckpt: str) -> dict[str, float]:
    """Refuse a collapsed model (depth stuck at a limit or constant) on up to 8 training frames."""
    from staticdepth.baseline.data import to_float
    from staticdepth.baseline.layers import disp_to_depth
    from staticdepth.baseline.scene_fit import check_not_collapsed

    model.eval()
    idx = torch.linspace(0, len(left) - 1, min(8, len(left))).long()
    inv = disp_to_depth(model(to_float(left[idx]).to(device))[0], conf.min_depth, conf.max_depth)[0]
    return check_not_collapsed((1.0 / inv).cpu().numpy(), conf, f" ({ckpt})")


def _check_compatible(state: Mapping[str, Any], conf: BaselineConfig, geo: StereoGeometry,
                      path: str, seq: str, seq_id: str, log: Callable[[str], None]) -> None:
    trained_on = state.get("sequence_id")
    if trained_on is None:                          # written before identities were stored
        log(f"warning: {path} does not record which sequence it was trained on (an older "
            f"checkpoint); taken as {seq}'s")
    elif trained_on != seq_id:
        raise InputError(f"checkpoint was trained on another sequence ({state['sequence']!r}, id "
                         f"{trained_on}) than {seq} holds now (id {seq_id}); use --overwrite to "
                         "retrain or another --checkpoint", path)
    old: BaselineConfig = state["config"]
    diff = sorted(k for k, v in conf.to_dict().items() if old.to_dict()[k] != v)
    if diff:
        raise InputError(f"checkpoint was trained with other settings ({', '.join(diff)}); "
                         "use --overwrite to start again or another --checkpoint", path)
    if abs(state["baseline_m"] - geo.baseline_m) > 1e-9 or \
            abs(state["focal_px"] - geo.focal_px) > 1e-6:
        raise InputError("checkpoint was trained on a sequence with another stereo geometry; "
                         "use --overwrite or another --checkpoint", path)
