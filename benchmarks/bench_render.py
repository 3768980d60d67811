"""Forward+backward shading throughput: particles x views x resolution, per backend.

Usage:
    python benchmarks/bench_render.py                       # 20 particles x 20 views at 64, 128, 256
    python benchmarks/bench_render.py --res 128 --backends eager compiled --repeats 10

Setting: rectified collocated views (the captures' case, one texel per pixel),
per-particle albedo (RGB), roughness and specular (RGB), normals held fixed;
the backward pass takes a gradient of the radiance w.r.t. every per-particle map.
Two paths: "images" returns the radiance images ``[n, V, 3, H, W]`` (memory-bound
at this size: the output alone is 79 MB at 128^2) and back-propagates a given
image gradient; "loss" fuses shading with the L1 likelihood (the sampler's hot
path) so the images are never materialised.
Prints milliseconds per forward+backward (median over repeats, after warm-up).
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade, shade_loss


def bench(n, V, res, backend, repeats, device="cpu", path="images"):
    views = collocated_views(V, radius=15.0, camera="rectified", resolution=res, power=1500.0, method="sobol")
    g = GBuffer.build(views, PlanarSample(10.0), device=device)
    gen = torch.Generator().manual_seed(0)
    maps = [torch.rand(n, c, res, res, generator=gen).to(device).requires_grad_() for c in (3, 1, 3)]
    normal = torch.tensor([0.0, 0.0, 1.0], device=device)[:, None, None].expand(3, res, res)
    gout = torch.rand(n, V, 3, res, res, generator=gen).to(device)

    target = torch.rand(V, res, res, 3, generator=gen).to(device)

    def step():
        x = SVBRDF(maps[0], 0.05 + 0.95 * maps[1], maps[2] * 0.5, normal)
        if path == "loss":  # the sampler's hot path: shading fused with the L1 likelihood
            return torch.autograd.grad(shade_loss(x, g, target, 100.0, backend=backend).sum(), maps)
        img = shade(x, g, backend=backend, channels_last=False)
        return torch.autograd.grad(img, maps, gout)

    t0 = time.perf_counter()
    step()  # warm-up (compiles for "compiled")
    warm = time.perf_counter() - t0
    for _ in range(2):
        step()
    ts = []
    for _ in range(repeats):
        if device != "cpu":
            torch.cuda.synchronize()
        t = time.perf_counter()
        step()
        if device != "cpu":
            torch.cuda.synchronize()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts) * 1e3, warm


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--res", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--backends", nargs="+", default=["eager", "compiled"])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--paths", nargs="+", default=["images", "loss"], choices=["images", "loss"],
                    help="images: shade -> [n,V,H,W,3] then backward; loss: fused shade + L1 loss -> [n] then backward")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    a = ap.parse_args()
    print(f"# shading forward+backward, {a.particles} particles x {a.views} views, device={a.device}, "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    print("| path | resolution | backend | ms / fwd+bwd | Mpix-evals/s | first call (s) |")
    print("|---|---|---|---|---|---|")
    for path in a.paths:
        for res in a.res:
            for b in a.backends:
                ms, warm = bench(a.particles, a.views, res, b, a.repeats, a.device, path)
                evals = a.particles * a.views * res * res
                print(f"| {path} | {res}^2 | {b} | {ms:.1f} | {evals / ms / 1e3:.0f} | {warm:.1f} |", flush=True)


if __name__ == "__main__":
    main()
