"""The metallic-roughness model (glTF's base colour, metallic, roughness): its BRDF against an independent
closed form, its sites, priors and presets, a posterior that finds a known metal and a known dielectric, and
the CLI (--model metallic_roughness) writing the base colour's, metallic's and roughness's std."""
import json
import warnings

import numpy as np
import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.cli.main import main
from bayes_brdf.errors import InputError
from bayes_brdf.models import metallic_roughness
from bayes_brdf.models.metallic import metallic_to_svbrdf
from bayes_brdf.render import PlanarSample, collocated_views
from bayes_brdf.render.shade import render
from tests.render import numpy_reference as ref


def _gltf_f(base, metallic, rough, n, l, v, f0=0.04):
    """glTF 2.0's metallic-roughness BRDF written out (numpy, float64), with the renderer's choices for the
    terms glTF leaves open: diffuse (1 - F0) c_diff / pi with c_diff = base (1 - metallic), GGX D with
    alpha = rough^2, Smith-Schlick G (k = alpha / 2), Schlick F (spherical-Gaussian exponent) from
    F0 = lerp(f0, base, metallic)."""
    base = np.asarray(base, float)
    F0 = f0 * (1 - metallic) + base * metallic
    c_diff = base * (1 - metallic)
    h = (l + v) / np.linalg.norm(l + v)
    nl, nv, nh, vh = (max(float(np.dot(a, b)), 1e-8) for a, b in ((n, l), (n, v), (n, h), (v, h)))
    a = rough * rough
    D = a * a / (np.pi * (nh * nh * (a * a - 1) + 1) ** 2)
    k = a / 2
    G = nl / (nl * (1 - k) + k) * nv / (nv * (1 - k) + k)
    F = F0 + (1 - F0) * 2.0 ** ((-5.55473 * vh - 6.98316) * vh)
    return c_diff * (1 - F0) / np.pi + D * F * G / (4 * nl * nv), nl


@pytest.mark.parametrize("base, metallic, rough", [((0.9, 0.6, 0.2), 1.0, 0.3),    # gold-ish metal
                                                   ((0.2, 0.5, 0.8), 0.0, 0.6),    # blue dielectric
                                                   ((0.7, 0.7, 0.7), 0.4, 0.15)])  # in between
def test_render_is_the_closed_form_of_the_gltf_brdf(base, metallic, rough):
    R = 5
    model = metallic_roughness(R)
    vals = {"base_color": torch.tensor(base, dtype=torch.float64)[:, None, None].expand(3, R, R),
            "metallic": torch.full((1, R, R), metallic, dtype=torch.float64),
            "roughness": torch.full((1, R, R), rough, dtype=torch.float64)}
    views = collocated_views(3, 2.5, camera="rectified", resolution=R, power=6.0)
    img = render(model.maps(vals), views, PlanarSample(2.0))[0].numpy()              # [V, R, R, 3]
    xs = ref.texel_centers(R, 2.0)
    ys = -ref.texel_centers(R, 2.0)
    for vi, view in enumerate(views):
        cam = np.asarray(view.camera.position, float)
        (light,) = view.point_lights
        for i, j in ((0, 0), (2, 3), (4, 1)):
            p = np.array([xs[j], ys[i], 0.0])
            v = (cam - p) / np.linalg.norm(cam - p)
            lv = np.asarray(light.position, float) - p
            d2 = float(lv @ lv)
            f, nl = _gltf_f(base, metallic, rough, np.array([0, 0, 1.0]), lv / np.sqrt(d2), v)
            want = f * nl * np.asarray(light.power, float) / d2
            np.testing.assert_allclose(img[vi, i, j], want, rtol=1e-9)


def test_maps_kd_and_f0_and_the_std_over_its_own_maps():
    b = torch.tensor([0.8, 0.5, 0.1])[:, None, None].expand(3, 2, 2)
    m = torch.tensor([[[0.0, 1.0], [0.5, 0.25]]])
    s = metallic_to_svbrdf(b, m, torch.full((1, 2, 2), 0.3), torch.tensor([0, 0, 1.0])[:, None, None])
    assert torch.allclose(s.albedo, b * (1 - m)) and torch.allclose(s.specular, 0.04 * (1 - m) + b * m)
    assert torch.allclose(s.albedo[:, 0, 1], torch.zeros(3)) and torch.allclose(s.specular[:, 0, 0], torch.full((3,), 0.04))
    # a posterior's std: base colour, metallic, roughness (its own maps); the renderer's kd and F0 on request
    model = metallic_roughness(2)
    g = torch.Generator().manual_seed(0)
    parts = {"base_color": torch.rand(6, 3, 2, 2, generator=g), "metallic": torch.rand(6, 1, 2, 2, generator=g),
             "roughness": 0.1 + 0.8 * torch.rand(6, 1, 2, 2, generator=g)}
    post = bb.Posterior(parts, torch.zeros(6), model=model, surface=PlanarSample(2.0))
    sd = post.std()
    assert list(sd) == ["base_color", "metallic", "roughness"]
    assert torch.allclose(sd["metallic"], parts["metallic"].std(0))
    kd = parts["base_color"] * (1 - parts["metallic"])
    assert torch.allclose(post.std("albedo"), kd.std(0))
    assert torch.allclose(post.std("specular"), (0.04 * (1 - parts["metallic"]) + parts["base_color"] * parts["metallic"]).std(0))


def test_options_presets_and_bad_values():
    m = bb.infer.__globals__["resolve_model"]("metallic_roughness")
    assert m.kind == "metallic_roughness" and m.latent_sites() == ["base_color", "metallic", "roughness"]
    assert m.to_dict()["model"] == "metallic_roughness"
    again = bb.models.from_preset(m.to_dict())
    assert again == m
    with pytest.raises(InputError, match="dielectric_f0"):
        metallic_roughness(4, dielectric_f0=1.5)
    with pytest.raises(InputError, match="normals"):
        metallic_roughness(4, normals="infer")
    with pytest.raises(InputError, match="unknown site"):
        metallic_roughness(4, prior={"albedo": bb.models.priors.uniform()})
    with pytest.raises(InputError, match="unknown key"):
        bb.models.from_preset({"model": "metallic_roughness", "specular": 0.5})


def _photos(base, metallic, rough, R=8, views=6, sigma=0.005, seed=0):
    """``views`` rectified collocated photos of a uniform metallic-roughness material, Gaussian noise ``sigma``."""
    vs = collocated_views(views, 2.5, camera="rectified", resolution=R, power=6.0, max_zenith=60, seed=seed)
    model = metallic_roughness(1)
    vals = {"base_color": torch.tensor(base).reshape(3, 1, 1), "metallic": torch.full((1, 1, 1), metallic),
            "roughness": torch.full((1, 1, 1), rough)}
    clean = render(model.maps(vals), vs, PlanarSample(2.0))[0]
    noisy = clean + sigma * torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed))
    return bb.Observations(vs, noisy, PlanarSample(2.0))


def _inside(post, truth: dict) -> bool:
    """Whether every true value is inside the posterior's central 90 % interval (5 % slack at the bounds)."""
    for site, t in truth.items():
        x = post.particles[site].flatten(1).double()
        lo, hi = torch.quantile(x, 0.05, dim=0), torch.quantile(x, 0.95, dim=0)
        t = torch.as_tensor(t, dtype=torch.float64).flatten()
        if not bool(((t >= lo - 0.005) & (t <= hi + 0.005)).all()):
            return False
    return True


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["spos", "emcee"])
def test_a_known_material_is_found_or_the_run_is_flagged(sampler):
    """One metallic-roughness BRDF (the model at resolution 1) from six 8x8 photos, noise 0.005. A gold-like
    metal: every sampler converges with the truth inside its 90 % intervals. A blue dielectric (4 % specular)
    has a local mode at roughness 0.75, metallic 0.09, 740 nats above the truth: a run either holds the truth
    inside its intervals or its checks flag it (SPOS finds it; emcee's walkers stay in the trap and say so)."""
    model = metallic_roughness(1)
    metal = {"base_color": (0.9, 0.6, 0.2), "metallic": 1.0, "roughness": 0.3}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bb.errors.ConvergenceWarning)
        post = bb.infer(model, _photos(*metal.values()), sampler, seed=0, progress=False)
    assert post.diagnostics["converged"], post.diagnostics["failed"]
    assert _inside(post, metal)
    assert float(post.mean("metallic")) > 0.95
    dielectric = {"base_color": (0.2, 0.5, 0.8), "metallic": 0.0, "roughness": 0.3}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bb.errors.ConvergenceWarning)
        post = bb.infer(model, _photos(*dielectric.values()), sampler, seed=0, progress=False)
    assert _inside(post, dielectric) or not post.diagnostics["converged"]
    if sampler == "spos":
        assert _inside(post, dielectric)


def test_cli_fit_with_the_metallic_roughness_model(tmp_path):
    cap = tmp_path / "cap"
    assert main(["render", "scratched_metal", "--views", "sobol:4", "--camera", "rectified", "--resolution", "8",
                 "--out", str(cap)]) == 0
    out = tmp_path / "fit"
    assert main(["fit", str(cap), "--model", "metallic_roughness", "--holdout", "3", "--steps", "60",
                 "--particles", "6", "--out", str(out)]) == 0
    for name in ("base_color", "metallic", "roughness"):
        assert (out / "std" / f"{name}.exr").is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert s["model"]["model"] == "metallic_roughness" and s["model"]["resolution"] == 8
    assert set(s["mean_param_std"]) == {"base_color", "metallic", "roughness"}
    assert s["heldout"]["pixels"] > 0
