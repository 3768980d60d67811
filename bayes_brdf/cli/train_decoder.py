"""``bayes-brdf train-decoder``: train the latent decoder's generator on the procedural materials."""
from __future__ import annotations

from pathlib import Path

from .common import positive_int


def add_parser(sub):
    t = sub.add_parser("train-decoder", help="train the latent_decoder model's generator (a VAE on the procedural "
                                             "materials)",
                       description="Train a StyleGAN2 generator as the decoder of a VAE on the six procedural "
                                   "materials with colour, scale, rotation and blend augmentations; write "
                                   "safetensors weights (plus OUT.curve.json, the training curve). Deterministic "
                                   "by seed on one machine; checkpoints to OUT.ckpt and resumes from it. The "
                                   "committed models/latent_decoder_64.safetensors is the default command's result.")
    t.add_argument("--preset", default="cpu64", choices=("cpu64", "cpu128"),
                   help="generator size (default: %(default)s: 64², W+ 10 x 128, 9 noise maps)")
    t.add_argument("--steps", type=positive_int, default=None, help="training steps (default: 8000)")
    t.add_argument("--batch", type=positive_int, default=None, help="materials per step (default: 16)")
    t.add_argument("--seed", type=int, default=0, help="seed of the data, augmentations and weights (default: 0)")
    t.add_argument("--threads", type=positive_int, default=2, help="torch threads (default: %(default)s)")
    t.add_argument("--out", default=None,
                   help="weights file (default: latent_decoder_64.safetensors in the current folder)")
    t.add_argument("--figures", default=None,
                   help="also write the training curve and a sample grid as PNGs into this folder")
    t.set_defaults(func=run)


def run(a) -> int:
    from ..io.outputs import check_file_target
    from ..training import TrainConfig, train_decoder

    out = Path(a.out or f"latent_decoder_{a.preset[3:]}.safetensors")
    check_file_target(str(out), option="--out")
    if a.figures:
        from ..io.outputs import check_folder
        check_folder(a.figures, option="--figures")
    cfg = TrainConfig(preset=a.preset, seed=a.seed, threads=a.threads,
                      **{k: v for k, v in (("steps", a.steps), ("batch", a.batch)) if v is not None})
    s = train_decoder(cfg, out)
    if a.figures:
        from ..plots import decoder_curve, decoder_samples
        from ..training.train import decoded_samples, read_curve
        fig = Path(a.figures)
        decoder_curve(read_curve(out), fig / f"{out.stem}_curve.png")
        decoder_samples(decoded_samples(out), fig / f"{out.stem}_samples.png")
    print(f"trained {cfg.preset} for {cfg.steps} steps in {s['seconds']:.0f} s (final L1 {s['final_l1']:.4f}) -> {out}")
    return 0
