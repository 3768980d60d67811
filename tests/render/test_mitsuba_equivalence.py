"""Our deferred shading of meshes against Mitsuba's own ``direct`` integrator (render.mitsuba_reference).

The reference shares only the mesh arrays, the maps, the views and the first ray with us: Mitsuba's
bitmap textures, a Dr.Jit BSDF written from the paper's formula, Mitsuba's point emitters and its own
shadow rays. The issue's bar is PSNR >= 35 dB (linear radiance, peak = max of our image, all pixels)
with shadows, on a non-convex shape and the bunny; with our pixel-centre rays the two agree to float32
precision except at a pixel or two on shadow edges, where the two shadow-ray offsets differ.
"""
import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from bayes_brdf.errors import InputError
from bayes_brdf.render import SVBRDF, PerspectiveCamera, PointLight, RectifiedCamera, View
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.mitsuba_reference import (Unshadowed, _bitmap_data, check_views, psnr, render_reference,
                                                 sinusoid_maps)
from bayes_brdf.render.shade import render, shade

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.needs_llvm

BAR_DB = 35.0            # the acceptance bar
NO_SHADOW_BELOW_DB = 30.0  # ours without visibility must miss the reference by far
AGREE = 1e-4             # per-pixel agreement, relative to the peak ...
AGREE_FRACTION = 0.999   # ... on all but a few shadow-edge pixels


@dataclasses.dataclass
class Case:
    mesh: Mesh
    views: list
    maps: SVBRDF
    ours: torch.Tensor        # [V, H, W, 3]
    ref: torch.Tensor         # Mitsuba, our pixel-centre rays
    unshadowed: torch.Tensor  # ours with every light visible


def _case(mesh, kind, resolution) -> Case:
    views, maps = check_views(mesh, kind, resolution), sinusoid_maps()
    ours = render(maps, views, mesh)[0]
    ref = render_reference(maps, views, mesh)
    unshadowed = shade(maps, GBuffer.build(views, Unshadowed(mesh), dtype=torch.float64))[0]
    return Case(mesh, views, maps, ours, ref, unshadowed)


@pytest.fixture(scope="module")
def block():
    return _case(Mesh.block_on_plane(), "block_on_plane", (56, 64))     # not square: checks the aspect


@pytest.fixture(scope="module")
def bunny(shared_data):
    path = shared_data / "psdr_assets" / "bunny_low.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found (the bunny of ../shared/data)")
    return _case(Mesh.load(path, up="y"), "bunny", 64)


def _report(name, c: Case):
    peak = float(c.ours.max())
    per_view = [round(psnr(c.ours[k], c.ref[k], peak), 1) for k in range(len(c.views))]
    err = (c.ours - c.ref).abs().amax(-1)
    agree = float((err <= AGREE * peak).double().mean())
    print(f"{name}: PSNR {psnr(c.ours, c.ref):.1f} dB (views {per_view}), without shadows "
          f"{psnr(c.unshadowed, c.ref, peak):.1f} dB, pixels within {AGREE:g} of the peak {agree:.5f}")
    return agree


# ---------------------------------------------------------------------- conventions
@pytest.mark.parametrize("channels", [3, 1])
def test_bitmap_rows_are_flipped_and_bilinear_clamped_like_grid_sample(channels):
    """Mitsuba's bitmap reads data row j at v = (j + 0.5) / H (row 0 at v = 0); ours reads texel row 0 at
    v = 1: _bitmap_data flips the rows, and then Mitsuba's lookup is ours (texel centres, border clamp)."""
    from bayes_brdf.mitsuba_env import mitsuba_variant
    g = torch.Generator().manual_seed(0)
    tex = torch.rand(channels, 5, 7, generator=g, dtype=torch.float64)
    uv = torch.rand(400, 2, generator=g, dtype=torch.float64) * 1.2 - 0.1        # also outside [0, 1]: clamp
    grid = torch.stack([2 * uv[:, 0] - 1, 1 - 2 * uv[:, 1]], -1).reshape(1, 1, -1, 2)
    want = F.grid_sample(tex[None], grid, mode="bilinear", padding_mode="border", align_corners=False)[0, :, 0]
    with mitsuba_variant() as mi:
        import drjit as dr

        def lookup(data):
            t = mi.load_dict({"type": "bitmap", "data": mi.TensorXf(data), "raw": True, "filter_type": "bilinear",
                              "wrap_mode": "clamp"})
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.uv = mi.Point2f(mi.Float(uv[:, 0].float().numpy()), mi.Float(uv[:, 1].float().numpy()))
            v = t.eval(si) if channels == 3 else [t.eval_1(si)]
            return torch.from_numpy(np.stack([np.asarray(x) for x in v]).astype(np.float64))

        got = lookup(_bitmap_data(tex))
        unflipped = lookup(np.ascontiguousarray(tex.float().numpy().transpose(1, 2, 0)))
        one = lookup(_bitmap_data(tex[:, :1, :1]))                             # a 1 x 1 map is doubled
    assert float((got - want).abs().max()) < 1e-6
    assert float((unflipped - want).abs().max()) > 0.1                           # rows really are upside down
    assert float((one - tex[:, 0, 0, None]).abs().max()) < 1e-6


# ---------------------------------------------------------------------- the equivalence
def test_block_on_plane_matches_mitsuba_with_its_shadows(block):
    agree = _report("block_on_plane", block)
    assert psnr(block.ours, block.ref) >= BAR_DB
    assert agree >= AGREE_FRACTION
    assert float((block.ref.sum(-1) > 0).double().mean()) > 0.2                  # a real image, not black


@pytest.mark.shared
def test_bunny_matches_mitsuba_with_its_shadows(bunny):
    agree = _report("bunny", bunny)
    assert psnr(bunny.ours, bunny.ref) >= BAR_DB
    assert agree >= AGREE_FRACTION


@pytest.mark.parametrize("name", ["block", pytest.param("bunny", marks=pytest.mark.shared)])
def test_the_check_cannot_pass_without_shadows(name, request):
    """Ours with every light visible misses the reference by far: the views' shadows matter."""
    c = request.getfixturevalue(name)
    assert psnr(c.unshadowed, c.ref, float(c.ours.max())) < NO_SHADOW_BELOW_DB
    for k in range(len(c.views)):                                                # every view has shadows
        assert float((c.unshadowed[k] - c.ours[k]).abs().amax(-1).gt(1e-3 * float(c.ours.max())).double().sum()) > 20


def test_faces_wound_against_their_normals_match_mitsuba_and_the_right_winding(block):
    """Every face of the block wound the other way, vertex normals kept: the reference and ours both shade by the
    normals (not black), as for the block wound right, shadows included."""
    m = block.mesh
    rewound = Mesh(m.vertices, m.faces[:, ::-1], m.uv, m.normals, name="block_rewound")
    ours = render(block.maps, block.views, rewound)[0]
    ref = render_reference(block.maps, block.views, rewound)
    peak = float(block.ours.max())
    assert psnr(ours, ref, peak) >= BAR_DB
    assert psnr(ref, block.ref, peak) >= BAR_DB
    assert float(((ours - block.ours).abs().amax(-1) <= AGREE * peak).double().mean()) >= AGREE_FRACTION


def test_the_reference_applies_the_normal_map(block):
    flat = dataclasses.replace(block.maps, normal=torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)[:, None, None]
                               .expand(3, 2, 2).clone())
    assert psnr(block.ours, render_reference(flat, block.views, block.mesh)) < 30.0


def test_mitsuba_sensor_matches_our_supersampled_render(block):
    """camera='sensor' (Mitsuba's perspective camera, box filter) averages pixel areas: it matches our
    render supersampled 4 x 4 and box-averaged; against our pixel centres it differs at edges."""
    ref = render_reference(block.maps, block.views, block.mesh, camera="sensor", spp=64)
    s = 4
    (h, w), V = block.views[0].resolution, len(block.views)
    big = [dataclasses.replace(v, camera=dataclasses.replace(v.camera, resolution=(h * s, w * s))) for v in block.views]
    ss = render(block.maps, big, block.mesh)[0].reshape(V, h, s, w, s, 3).mean((2, 4))
    peak = float(block.ours.max())
    print(f"sensor, 64 spp: {psnr(ss, ref, peak):.1f} dB against ours 4x4-supersampled, "
          f"{psnr(block.ours, ref):.1f} dB against our pixel centres")
    assert psnr(ss, ref, peak) >= BAR_DB
    assert psnr(block.ours, ref) >= 25.0


# ---------------------------------------------------------------------- what it refuses
def test_refuses_what_mitsuba_cannot_represent():
    mesh, maps = Mesh.sphere(rings=4, segments=8), SVBRDF.constant()
    cam = PerspectiveCamera((0, 0, 4.0), resolution=8)
    with pytest.raises(InputError, match="PerspectiveCamera"):
        render_reference(maps, [View(RectifiedCamera((0, 0, 4.0), 8), (PointLight((0, 0, 4.0)),))], mesh)
    with pytest.raises(InputError, match="falloff"):
        render_reference(maps, [View(cam, (PointLight((0, 0, 4.0), falloff=False),))], mesh)
    two = SVBRDF(*(t.expand(2, *t.shape) for _, t in maps.items()))
    with pytest.raises(InputError, match="particles"):
        render_reference(two, [View.collocated(cam)], mesh)
    with pytest.raises(InputError, match="camera"):
        render_reference(maps, [View.collocated(cam)], mesh, camera="pinhole")
    with pytest.raises(InputError, match="variant"):
        render_reference(maps, [View.collocated(cam)], mesh, variant="scalar_rgb")


def test_the_bsdf_sample_pdf_and_eval_agree():
    """The BSDF's sampling interface (unused by point lights) is consistent: weight * pdf = eval, pdf(wo) = pdf."""
    from bayes_brdf.mitsuba_env import mitsuba_variant
    from bayes_brdf.render.mitsuba_reference import SCENES
    mesh, maps = Mesh.sphere(rings=16, segments=32), sinusoid_maps(8)
    cam = PerspectiveCamera((0.3, -0.5, 3.0), resolution=16)
    with mitsuba_variant() as mi:
        import drjit as dr
        rs = SCENES.get(mesh, mi.variant())
        rs.set_maps(maps)
        o, d = cam.rays()
        d = d.reshape(3, -1).numpy()
        si = rs.scene.ray_intersect(mi.Ray3f(mi.Point3f(*o.tolist()), mi.Vector3f(*(mi.Float(x) for x in d))))
        ctx = mi.BSDFContext()
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(1, d.shape[1])
        bs, weight = rs.bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), si.is_valid())
        value, pdf = rs.bsdf.eval_pdf(ctx, si, bs.wo, si.is_valid())
        ok = si.is_valid() & (bs.pdf > 1e-3)
        dr.eval(weight, value, pdf, ok)
        ok = np.asarray(ok)
        w, v = (np.stack([np.asarray(x[i]) for i in range(3)])[:, ok] for x in (weight, value))
        assert ok.sum() > 50
        assert np.allclose(w * np.asarray(bs.pdf)[ok], v, rtol=1e-4, atol=1e-7)
        assert np.allclose(np.asarray(pdf)[ok], np.asarray(bs.pdf)[ok], rtol=1e-5)
        assert np.allclose(np.asarray(rs.bsdf.pdf(ctx, si, bs.wo, si.is_valid()))[ok], np.asarray(bs.pdf)[ok])
