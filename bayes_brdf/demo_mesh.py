"""The demo's object section: the same story on a mesh (section 7 of ``bayes-brdf demo``'s report).

A procedural material covers a mesh through its uv (the built-in bowl, which shadows itself, or a
mesh file such as the Stanford bunny with its xatlas atlas); a few flash photos from perspective
cameras around it are rendered with Mitsuba-ray-cast G-buffers and shadows; the posterior of the
per-texel maps is sampled; the report shows the maps in texture space with the texels no photo sees
(they keep the prior: maximal std), the predicted std on novel views next to the actual error, and
the next views recommended by mutual information among candidate cameras all around the object.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import torch

from . import plots
from .errors import ConvergenceWarning, InputError
from .guidance import SyntheticCapture, recommend, score_views
from .inference import infer
from .materials import make_material
from .models.material import per_texel
from .render.gbuffer import GBUFFERS
from .render.shade import render
from .render.views import collocated_views
from .uncertainty import correlations, image_std

#: built-in shapes the demo can use by name
SHAPES = ("bowl", "sphere", "block")


def load_demo_mesh(spec: str, up: str = "z"):
    """A built-in shape by name (:data:`SHAPES`) or a mesh file (its own unit is taken as the scene's)."""
    from .render.mesh import Mesh

    if spec in SHAPES:
        return {"bowl": Mesh.bowl, "sphere": Mesh.sphere, "block": Mesh.block_on_plane}[spec]()
    p = Path(spec)
    if not p.is_file():
        raise InputError(f"--mesh {spec!r} is neither a mesh file nor a built-in shape",
                         fix=f"use one of {', '.join(SHAPES)}, none, or an OBJ/PLY/GLB file")
    return Mesh.load(p, up=up)


def mesh_section(rep, out: Path, cfg: dict, progress: bool, log) -> dict:
    """Section 7 of the report; returns its numbers for ``demo.json``."""
    t0 = time.perf_counter()
    mesh = load_demo_mesh(str(cfg["mesh"]), cfg.get("mesh_up", "z"))
    T = int(cfg.get("mesh_texels") or 2 * int(cfg["resolution"]))
    res = int(cfg.get("mesh_resolution") or 2 * int(cfg["resolution"]))
    steps = int(cfg.get("mesh_steps") or min(600, int(cfg["steps"])))
    seed = int(cfg["seed"])
    truth = make_material(cfg["material"], T, seed=seed).to(torch.float32)
    dist = 2.6 * mesh.radius
    light = dict(power=(dist ** 2) * 1.2, target=mesh.center, resolution=res, fov=45)
    views = collocated_views(int(cfg["mesh_views"]), dist, method="fibonacci", max_zenith=70, **light)
    cap = SyntheticCapture(truth, mesh, noise_sigma=float(cfg["noise"]), seed=seed)
    obs = cap(views)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        post = infer(per_texel(T), obs, "spos", seed=seed, particles=int(cfg["particles"]),
                     steps=steps, progress=progress)
    post.save(out / "mesh" / "posterior.safetensors")
    m, std = post.maps("map"), post.std()
    idx = GBUFFERS.get(tuple(views), mesh).texel_index(T)
    seen = torch.zeros(T * T, dtype=torch.bool)
    seen[idx[idx >= 0]] = True
    unseen = ~seen.reshape(T, T)
    va = float(std["albedo"].max())
    vr = float(std["roughness"].max())
    photos = plots.panel_grid(out / "mesh" / "photos.png", [
        [plots.rgb_panel(obs.images[i], f"photo {i}") for i in range(min(4, len(obs)))]], panel_size=(2.6, 2.5))
    texture = plots.panel_grid(out / "mesh" / "texture.png", [
        [plots.rgb_panel(truth.albedo, "true albedo (texture space)"), plots.rgb_panel(m.albedo, "MAP albedo"),
         plots.map_panel(std["albedo"], "posterior std: albedo", vmax=va, masks={"no photo sees it": unseen}),
         plots.map_panel(std["roughness"], "posterior std: roughness", vmax=vr,
                         masks={"no photo sees it": unseen})]])
    novel = collocated_views(2, dist, method="random", seed=10_000 + seed, max_zenith=80, **light)
    nt = render(truth, novel, mesh)[0]
    pred = render(m, novel, mesh)[0]
    err = (pred - nt).abs()
    sd = image_std(post, novel, mesh)
    on = GBUFFERS.get(tuple(novel), mesh).mask
    corr = correlations(sd[on], err[on])
    vmax = float(torch.quantile(torch.cat([sd[on].flatten(), err[on].flatten()]), 0.99))
    novel_png = plots.panel_grid(out / "mesh" / "novel_views.png", [
        [plots.rgb_panel(nt[j], f"novel view {j}: truth"), plots.rgb_panel(pred[j], "MAP render"),
         plots.map_panel(err[j], "|MAP render - truth|", vmax=vmax, masks={"off the object": ~on[j]}),
         plots.map_panel(sd[j], "predicted std (Eq. 11)", vmax=vmax, masks={"off the object": ~on[j]})]
        for j in range(len(novel))])
    cands = collocated_views(int(cfg["mesh_candidates"]), dist, method="sobol", seed=seed, max_zenith=90, **light)
    scores = score_views(post, cands, mesh, seed=seed)
    rec = recommend(post, cands, int(cfg["k"]), radius=float(cfg["radius"]), scores=scores, surface=mesh)
    cand_png = out / "mesh" / "candidates.png"
    plots.plot_candidates(cand_png, cands, scores.mi.numpy(), rec.indices,
                          f"{len(cands)} candidate cameras around the {mesh.name}, MI", centre=mesh.center)
    secs = time.perf_counter() - t0
    frac = float(seen.float().mean())
    log(f"demo: section 7: mesh '{mesh.name}' ({mesh.num_faces} faces): {len(obs)} photos, {T}x{T} texels of which "
        f"{frac:.0%} seen; unseen texels' std {float(std['albedo'].mean(0)[unseen].mean()):.3f} vs seen "
        f"{float(std['albedo'].mean(0)[~unseen].mean()):.3f}; novel views std vs error Spearman "
        f"{corr['spearman']:.2f} ({secs:.0f} s)")
    rep.heading(f"7. An object: the {mesh.name} ({mesh.num_faces} faces)")
    rep.text(f"The same material on a mesh, through its texture atlas: {len(obs)} flash photos at {res}x{res} from "
             f"perspective cameras around it (G-buffers ray cast by Mitsuba, shadows included), per-texel maps at "
             f"{T}x{T} sampled with SPOS ({post.num_particles} particles, {steps} steps; convergence "
             f"checks {'passed' if (post.diagnostics or {}).get('converged') else 'not all passed'}).")
    rep.images([(photos, "some of the photos")], width=800)
    rep.images([(texture, "texture space: the maps the posterior is over. Cyan: texels no photo sees (the "
                          f"parts that face away from every camera, and atlas gaps: {1 - frac:.0%} of the texels); they keep the prior, so their "
                          "std is the largest")], width=1060)
    rep.images([(novel_png, "novel views of the object: truth, MAP render, its error and the predicted std on "
                            "one shared range")], width=1060)
    rep.table([["texels seen by a photo", f"{frac:.0%}"],
               ["mean albedo std, seen texels", float(std["albedo"].mean(0)[~unseen].mean())],
               ["mean albedo std, unseen texels (prior: 0.289)", float(std["albedo"].mean(0)[unseen].mean())],
               ["novel views: Pearson(std, |error|)", corr["pearson"]],
               ["novel views: Spearman(std, |error|)", corr["spearman"]]], header=["object", "value"])
    rep.images([(cand_png, "candidate cameras around the object seen from above, coloured "
                                                 "by mutual information; circles: the recommended next views")],
               width=460)
    rep.text("The recommended views look at what the photos have not covered yet: grazing and low directions "
             "that see the parts the first photos missed.", cls="note")
    return {"mesh": mesh.name, "faces": mesh.num_faces, "views": len(obs), "texels": T, "seen_fraction": frac,
            "novel_correlation": corr, "recommended": rec.indices, "seconds": secs}
