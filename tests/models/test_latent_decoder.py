"""The latent decoder: MaterialGAN's channel decoding, the model protocol in map space, and known posteriors."""
import math

import numpy as np
import pyro
import pyro.distributions as dist
import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.materials import height_to_normal, make_material
from bayes_brdf.materials.augment import dihedral
from bayes_brdf.models.svbrdf_channels import decode, encode
from bayes_brdf.posterior import Posterior
from bayes_brdf.potential import Potential
from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.shade import render

SURF = PlanarSample(2.0)


def _obs(res=8, views=4, maps=None, noise=0.0, seed=0):
    vs = bb.render.collocated_views(views, 3.0, camera="rectified", resolution=res, power=10.0)
    img = render(maps if maps is not None else SVBRDF.constant(0.5, 0.3), vs, SURF)[0]
    if noise:
        img = img + noise * torch.randn(img.shape, generator=torch.Generator().manual_seed(seed))
    return bb.Observations(vs, img, SURF)


# ---------------------------------------------------------------------- channels
def test_decoding_is_materialgans_formula():
    rng = np.random.default_rng(0)
    t = rng.uniform(-1.4, 1.4, size=(9, 5, 5))
    t[3:5, 0, 0] = [0.9, 0.9]                       # x² + y² > 1: z clamps to ~0
    m = decode(torch.tensor(t, dtype=torch.float64))
    g = lambda x, lo: ((np.clip(x, lo, 1) + 1) / 2) ** 2.2  # noqa: E731
    np.testing.assert_allclose(m.albedo.numpy(), g(t[0:3], -1), rtol=1e-12)
    np.testing.assert_allclose(m.specular.numpy(), g(t[6:9], -1), rtol=1e-12)
    np.testing.assert_allclose(m.roughness.numpy(), np.maximum(g(t[5:6], -0.3), 1e-6), rtol=1e-12)
    xy = np.clip(t[3:5], -1, 1)
    z = np.sqrt(1 - np.clip((xy ** 2).sum(0, keepdims=True), 0, 1 - 1e-6))
    n = np.concatenate([xy, z]) / np.linalg.norm(np.concatenate([xy, z]), axis=0, keepdims=True)
    np.testing.assert_allclose(m.normal.numpy(), n, rtol=1e-10, atol=1e-12)
    assert m.roughness.min() >= 0.35 ** 2.2 - 1e-12      # MaterialGAN's roughness floor


def test_encode_inverts_decode_on_procedural_materials():
    for name in ("tiles", "scratched_metal", "leather"):
        m = make_material(name, 32, seed=1)
        d = decode(encode(m))
        torch.testing.assert_close(d.albedo, m.albedo, atol=1e-5, rtol=0)
        torch.testing.assert_close(d.normal, m.normal, atol=1e-5, rtol=0)
        torch.testing.assert_close(d.roughness, m.roughness.clamp_min(0.35 ** 2.2).expand_as(d.roughness),
                                   atol=1e-5, rtol=0)
    with pytest.raises(InputError, match=r"\[\.\.\., 9, H, W\]"):
        decode(torch.zeros(3, 4, 4))


@pytest.mark.parametrize("k", range(8))
def test_dihedral_turns_normals_with_the_map(k):
    """Transforming the normal map must equal the normals of the transformed height field."""
    h = make_material("leather", 32, seed=2)  # its albedo, roughness and specular ride along
    u = torch.linspace(0, 1, 33)[:-1]
    height = 0.01 * torch.sin(2 * math.pi * (2 * u[None] + 3 * u[:, None] ** 2)) + 0.004 * torch.cos(6 * math.pi * u[:, None])
    chans = encode(SVBRDF(h.albedo, h.roughness, h.specular, height_to_normal(height)))[None]
    turned = dihedral(chans, k)[0]
    # the same symmetry applied to the height field's index grid, then normals computed afresh
    hk = height
    if k & 4:
        hk = hk.T
    if k & 2:
        hk = hk.flip(-1)
    if k & 1:
        hk = hk.flip(-2)
    want = height_to_normal(hk)
    torch.testing.assert_close(turned[3:5], want[0:2], atol=1e-5, rtol=0)


# ---------------------------------------------------------------------- the model protocol, a known answer
class LinearDecoder:
    """A user's own model on the protocol: albedo maps = 0.5 + A w, w ~ N(0, I), Gaussian likelihood."""

    def __init__(self, A, sigma):
        self.A, self.sigma = A, sigma          # A: [3 * R * R, d]

    def latent_sites(self):
        return ["w"]

    def maps(self, values):
        w = values["w"]
        R = int(math.isqrt(self.A.shape[0] // 3))
        alb = (0.5 + w @ self.A.T).reshape(*w.shape[:-1], 3, R, R)
        return SVBRDF(alb, torch.full((1, 1, 1), 0.3, dtype=w.dtype), torch.full((3, 1, 1), 0.04, dtype=w.dtype),
                      torch.tensor([0.0, 0.0, 1.0], dtype=w.dtype).reshape(3, 1, 1))

    def __call__(self, data):
        w = pyro.sample("w", dist.Normal(torch.zeros(self.A.shape[1], dtype=data.dtype), 1.0).to_event(1))
        bb.models.observe(data, self.maps({"w": w}), sigma=self.sigma, kind="gaussian")


def test_linear_decoder_posterior_matches_the_closed_form_in_map_space():
    torch.manual_seed(0)
    R, d, sigma = 4, 3, 0.02
    A = 0.08 * torch.randn(3 * R * R, d, dtype=torch.float64)
    model = LinearDecoder(A, sigma)
    w_true = torch.tensor([0.7, -0.4, 1.1], dtype=torch.float64)
    obs = _obs(res=8, views=4, maps=model.maps({"w": w_true[None]}).particle(0), noise=sigma, seed=1)
    data = bb.models.ModelData.from_observations(obs, dtype=torch.float64)
    # the renders are affine in w: columns of J from unit vectors (exact for an affine map)
    basis = torch.cat([torch.zeros(1, d, dtype=torch.float64), torch.eye(d, dtype=torch.float64)])
    imgs = render(model.maps({"w": basis}), obs.views, SURF)            # [1 + d, V, H, W, 3] like the photos
    c = imgs[0].reshape(-1)
    J = (imgs[1:].reshape(d, -1) - c).T                                 # [V H W 3, d]
    used = data.weight[..., None].expand(*data.weight.shape, 3).reshape(-1).bool()
    y = obs.images.to(torch.float64).reshape(-1)
    Jw, r = J[used], (y - c)[used]
    prec = torch.eye(d, dtype=torch.float64) + Jw.T @ Jw / sigma ** 2
    cov = torch.linalg.inv(prec)
    mu = cov @ Jw.T @ r / sigma ** 2
    map_sd = (A @ cov @ A.T).diagonal().sqrt().reshape(3, R, R)
    post = bb.infer(model, obs, "nuts", particles=200, steps=1200, dtype=torch.float64, progress=False, seed=0,
                    params={"thin": 5, "warmup_steps": 200})
    w = post.particles["w"]
    assert ((w.mean(0) - mu).abs() / cov.diagonal().sqrt()).max() < 0.35
    np.testing.assert_allclose(w.std(0).numpy(), cov.diagonal().sqrt().numpy(), rtol=0.2)
    sd = post.std()                                     # map space: the decoded albedo's std
    assert set(sd) == {"albedo"} and sd["albedo"].shape == (3, R, R)
    np.testing.assert_allclose(sd["albedo"].numpy(), map_sd.numpy(), rtol=0.25)
    assert torch.equal(post.std("w"), w.std(0))          # a site's own std stays available


# ---------------------------------------------------------------------- the latent decoder
@pytest.fixture(scope="module")
def decoder():
    return bb.models.latent_decoder(project_steps=20, sigma=0.01)


def test_latent_decoder_sites_and_shapes(decoder):
    g = decoder.generator
    assert decoder.latent_sites() == ["w_plus", "noise"] and g.num_ws == 10 and decoder.resolution == 64
    assert decoder.noise_size() == 16 + 2 * (64 + 256 + 1024 + 4096)
    vals = {"w_plus": g.w_avg.expand(2, 10, -1), "noise": torch.zeros(2, decoder.noise_size())}
    m = decoder.maps(vals)
    assert m.albedo.shape == (2, 3, 64, 64) and m.normal.shape == (2, 3, 64, 64)
    assert 0 <= float(m.albedo.min()) and float(m.albedo.max()) <= 1
    torch.testing.assert_close(m.normal.norm(dim=1), torch.ones(2, 64, 64))


@pytest.mark.filterwarnings("ignore::bayes_brdf.errors.ConvergenceWarning")
def test_latent_decoder_std_is_over_the_decoded_maps(decoder):
    obs = _obs(res=16, views=3)
    post = bb.infer(decoder, obs, "spos", particles=5, steps=3, progress=False, seed=0)
    sd = post.std()
    assert set(sd) == {"albedo", "roughness", "specular", "normal"}
    each = [decoder.maps({k: v[i:i + 1] for k, v in post.particles.items()}) for i in range(5)]
    for name in sd:
        stack = torch.cat([getattr(m, name) for m in each])
        torch.testing.assert_close(sd[name], stack.std(0), atol=1e-4, rtol=1e-3)   # float32, other batch sizes
        assert float(sd[name].max()) > 0
    mean = post.maps("mean")
    torch.testing.assert_close(mean.albedo, torch.cat([m.albedo for m in each]).mean(0), atol=1e-4, rtol=1e-3)
    assert post.std("w_plus").shape == (10, 128)       # the latent coordinates' std is still there


def test_projection_lowers_the_energy_and_starts_every_particle_near_it(decoder):
    truth = make_material("tiles", 64, seed=100_000)
    obs = _obs(res=32, views=4, maps=truth)
    data = bb.models.ModelData.from_observations(obs)
    pot = Potential(decoder, (data,))
    z0 = pot.init(3, seed=0)
    assert z0.shape == (3, pot.dim)
    e_avg = pot.energy(pot.to_unconstrained({"w_plus": decoder.generator.w_avg.expand(1, 10, -1),
                                             "noise": torch.zeros(1, decoder.noise_size())}), jacobian=False)
    e0 = pot.energy(z0, jacobian=False)
    assert float(e0.max()) < float(e_avg[0])
    assert torch.equal(pot.init(3, seed=0), z0) and not torch.equal(pot.init(3, seed=1), z0)


@pytest.mark.filterwarnings("ignore::bayes_brdf.errors.ConvergenceWarning")
def test_latent_decoder_round_trips_through_a_posterior_file(decoder, tmp_path):
    obs = _obs(res=16, views=3)
    post = bb.infer(decoder, obs, "spos", particles=3, steps=2, progress=False, map_steps=0)
    back = Posterior.load(post.save(tmp_path / "p.safetensors"))
    assert back.model is not None and back.meta["model"]["weights_digest"] == decoder.to_dict()["weights_digest"]
    torch.testing.assert_close(back.maps("mean").albedo, post.maps("mean").albedo)


def test_latent_decoder_options_are_checked():
    with pytest.raises(InputError, match="prior must be one of"):
        bb.models.latent_decoder(prior="uniform")
    with pytest.raises(InputError, match="no decoder weights"):
        bb.models.latent_decoder("no_such_weights")
    with pytest.raises(InputError, match="changed since"):
        bb.models.latent_decoder(weights_digest="0123456789abcdef")
    m = bb.models.from_preset(bb.presets.load_preset("models", "latent_decoder"))
    assert m.prior == "flat" and m.noise == "infer"


def test_gaussian_prior_adds_its_log_density(decoder):
    obs = _obs(res=16, views=3)
    data = bb.models.ModelData.from_observations(obs)
    flat = Potential(decoder, (data,))
    gauss = Potential(bb.models.latent_decoder(prior="gaussian", sigma=0.01), (data,))
    g = decoder.generator
    w = g.w_avg + 0.5 * g.w_std * torch.randn(2, 10, 128, generator=torch.Generator().manual_seed(0))
    z = flat.to_unconstrained({"w_plus": w, "noise": torch.zeros(2, decoder.noise_size())})
    diff = gauss.energy(z) - flat.energy(z)
    want = -dist.Normal(g.w_avg, g.w_std).log_prob(w).sum((1, 2))
    torch.testing.assert_close(diff, want, rtol=1e-4, atol=1e-2)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_every_sampler_runs_on_the_latent_decoder():
    import warnings
    decoder = bb.models.latent_decoder(noise="zero", project_steps=5, sigma=0.01)   # W+ only: 1280 dimensions
    obs = _obs(res=16, views=3)
    for name in ("spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts"):
        kw = {"params": {"warmup_steps": 2, "thin": 1, "max_tree_depth": 2}, "steps": 6} if name == "nuts" \
            else {"steps": 3}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            post = bb.infer(decoder, obs, name, particles=4, seed=0, progress=False, map_steps=0, **kw)
        assert torch.isfinite(post.energies).all(), name
        assert set(post.std()) == {"albedo", "roughness", "specular", "normal"}, name


# ---------------------------------------------------------------------- the generator's fast path
def _generator_grads(g, impl, n=3, seed=0):
    """The synthesis ``impl`` on seeded W+ and noise: its output and the gradients of a weighted sum of it with
    respect to W+, the noise maps and every parameter that requires one."""
    gen = torch.Generator().manual_seed(seed)
    p = g.synthesis.const
    w = (g.w_avg + 0.5 * torch.randn(n, g.num_ws, g.cfg.w_dim, generator=gen, dtype=torch.float64).to(p))
    w.requires_grad_(True)
    noise = [torch.randn(n, 1, *s, generator=gen, dtype=torch.float64).to(p).requires_grad_(True)
             for s in g.noise_shapes()]
    y = impl(w, noise)
    wy = 1 + 0.5 * torch.cos(torch.arange(y.numel(), dtype=torch.float64)).reshape(y.shape).to(y)
    params = [q for q in g.synthesis.parameters() if q.requires_grad]
    grads = torch.autograd.grad((y * wy).sum(), [w, *noise, *params])
    return [y.detach(), *grads]


def test_fast_synthesis_is_the_reference_one_in_float64(decoder):
    """The model's synthesis (channels-last, regrouped factors, one-pass epilogue, 4x4 FIR) is the same map as the
    straightforward one, forward and backward (float64: no rounding, no leaky-ReLU kink flips)."""
    import copy
    g = copy.deepcopy(decoder.generator).double()
    fast, ref = _generator_grads(g, g.synthesis), _generator_grads(g, g.synthesis.reference)
    assert fast[0].is_contiguous() and fast[0].shape == ref[0].shape
    for a, b in zip(fast, ref):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12 * float(b.abs().max()))


def test_fast_synthesis_trains_like_the_reference():
    """Weights that require gradients (training): the same parameter gradients, float64, random weights with a
    nonzero noise strength and bias (the trained file's noise strengths could hide a wrong one)."""
    from bayes_brdf.models.stylegan import Generator, GeneratorConfig
    torch.manual_seed(0)
    g = Generator(GeneratorConfig(resolution=16, w_dim=8, z_dim=8, mapping_layers=2, fmaps_base=64,
                                  fmaps_max=8)).double()
    with torch.no_grad():
        for name, q in g.named_parameters():
            if name.endswith("noise_strength") or name.endswith("bias"):
                q.copy_(0.3 * torch.randn(q.shape, dtype=q.dtype))
    fast, ref = _generator_grads(g, g.synthesis, n=2), _generator_grads(g, g.synthesis.reference, n=2)
    assert len(fast) > 1 + g.num_ws + len(g.noise_shapes())
    for a, b in zip(fast, ref):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12 * float(b.abs().max()))


def test_fast_synthesis_in_float32_is_the_reference_to_rounding(decoder):
    """float32 (what a fit runs): the maps to ~1e-6 of their range, the energy's gradient over W+ to 1e-4 in norm
    (one leaky-ReLU input that rounds across zero moves a few gradient entries; float64 above is exact)."""
    import copy
    g = decoder.generator
    g64 = copy.deepcopy(g).double()
    fast, ref, exact = (_generator_grads(g, g.synthesis), _generator_grads(g, g.synthesis.reference),
                        _generator_grads(g64, g64.synthesis.reference))
    rel = lambda a, b: float((a.double() - b).norm() / b.norm())  # noqa: E731
    assert rel(fast[0], exact[0]) < 1e-5 and rel(ref[0], exact[0]) < 1e-5
    assert rel(fast[1], exact[1]) < 1e-4
