"""Stereo-baseline training and prediction throughput (images/s), CPU and CUDA where present.

Each row is measured in this run: a full training step (forward at 4 scales, warps, SSIM losses,
backward, Adam) and prediction, against a reference measured the same way, ResNet18-encoder-only
forward + backward + Adam on the same batch, so the ratio says what the decoder and the stereo loss
cost on top of the encoder. Data are random tensors (throughput does not depend on content).

    .venv/bin/python benchmarks/bench_baseline.py [--preset default] [--batch-size 4] [--steps 3]
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from staticdepth.baseline.config import preset
from staticdepth.baseline.network import build_model
from staticdepth.baseline.train import train_step
from staticdepth.cli import parse_overrides


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _interleaved(fns: dict, steps: int, device: torch.device) -> dict[str, float]:
    """Median seconds per call of each function, calls interleaved round by round so that a
    change in the machine's load affects every function alike."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for fn in fns.values():               # warm-up (allocations, cuDNN autotuning)
        fn()
    for _ in range(steps):
        for k, fn in fns.items():
            _sync(device)
            t0 = time.perf_counter()
            fn()
            _sync(device)
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def bench(device: torch.device, conf, batch_size: int, steps: int) -> dict[str, float]:
    torch.manual_seed(0)
    model = build_model(conf, load_weights=False).to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=conf.lr)
    b, h, w = batch_size, conf.height, conf.width
    batch = {"image": torch.rand(b, 3, h, w), "target": torch.rand(b, 3, h, w),
             "source": torch.rand(b, 3, h, w), "direction": torch.ones(b),
             "focal_px": torch.full((b,), 0.58 * w), "baseline_m": torch.full((b,), 0.27)}
    batch = {k: v.to(device) for k, v in batch.items()}
    enc_opt = torch.optim.Adam(model.encoder.parameters(), lr=conf.lr)

    def train():
        model.train()
        train_step(model, batch, conf, opt)

    def encoder_step():
        model.train()
        enc_opt.zero_grad(set_to_none=True)
        sum(f.mean() for f in model.encoder(batch["image"])).backward()
        enc_opt.step()

    @torch.no_grad()
    def predict():
        model.eval()
        model(batch["image"])[0]
    t = _interleaved({"train": train, "encoder": encoder_step, "predict": predict}, steps, device)
    t_train, t_ref, t_pred = t["train"], t["encoder"], t["predict"]
    return {"train_img_s": b / t_train, "encoder_img_s": b / t_ref, "predict_img_s": b / t_pred,
            "train_over_encoder": t_train / t_ref}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="default")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE")
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's choice)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    conf = preset(args.preset, parse_overrides(args.set))
    devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    print(f"stereo baseline, preset {args.preset}: {conf.width}x{conf.height}, ResNet18 width "
          f"{conf.encoder_width}, batch {args.batch_size}, {args.steps} interleaved rounds "
          f"(median), torch {torch.__version__}, {torch.get_num_threads()} CPU threads")
    print(f"{'device':8} {'train img/s':>12} {'encoder-only img/s':>19} {'train/encoder':>14} "
          f"{'predict img/s':>14}")
    for dev in devices:
        r = bench(dev, conf, args.batch_size, args.steps)
        print(f"{dev.type:8} {r['train_img_s']:12.2f} {r['encoder_img_s']:19.2f} "
              f"{r['train_over_encoder']:13.2f}x {r['predict_img_s']:14.2f}")
    if len(devices) == 1:
        print("CUDA: not available on this machine")


if __name__ == "__main__":
    main()
