"""Mesh G-buffers by Mitsuba ray casting, against closed forms: the analytic sphere, the plane, box shadows."""
import math

import numpy as np
import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.render import SVBRDF, PerspectiveCamera, PlanarSample, PointLight, RectifiedCamera, View
from bayes_brdf.render.gbuffer import GBUFFERS, GBuffer
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.shade import render

pytestmark = pytest.mark.needs_llvm


def _cams():
    return [PerspectiveCamera((0.0, 0.3, 4.0), resolution=48, fov=40),
            PerspectiveCamera((3.0, -1.0, 1.5), up=(0, 0, 1), resolution=48, fov=40)]


def test_sphere_hits_positions_normals_and_uv_match_the_analytic_sphere():
    r = 1.0
    hits = Mesh.sphere(r, rings=96, segments=192).intersect(_cams())
    for k, cam in enumerate(_cams()):
        o, d = cam.rays(dtype=torch.float64)
        b = (o[:, None, None] * d).sum(0)                  # analytic ray-sphere hit: t^2 + 2 b t + |o|^2 - r^2 = 0
        disc = b * b - (o @ o - r * r)
        inside = disc > 0.02                                # leave the silhouette's grazing pixels out
        m = hits.mask[k]
        assert bool((m == (disc > 0))[disc.abs() > 0.02].all())        # which pixels see the sphere
        t = -b - disc.clamp_min(0).sqrt()
        p = o[:, None, None] + t * d
        sel = inside & m
        assert int(sel.sum()) > 400
        assert float((hits.position[k][:, sel] - p[:, sel]).norm(dim=0).max()) < 2e-3 * r   # tessellation sag
        nrm = p / r
        assert float((hits.normal[k][:, sel] - nrm[:, sel]).norm(dim=0).max()) < 2e-3
        frame = torch.stack([hits.tangent[k], hits.bitangent[k], hits.normal[k]])[:, :, sel]
        gram = torch.einsum("icp,jcp->ijp", frame, frame)
        assert float((gram - torch.eye(3, dtype=torch.float64)[..., None]).abs().max()) < 1e-5   # orthonormal
        phi = torch.atan2(p[1], p[0]) % (2 * math.pi)
        theta = torch.acos(p[2].clamp(-1, 1))
        away = sel & (phi > 0.05) & (phi < 2 * math.pi - 0.05)          # off the u seam
        u, v = (hits.uv[k][..., 0] + 1) / 2, (1 - hits.uv[k][..., 1]) / 2
        assert float((u[away] - phi[away] / (2 * math.pi)).abs().max()) < 1e-3
        assert float((v[away] - (1 - theta[away] / math.pi)).abs().max()) < 1e-3
        # the tangent follows +u: along d p / d phi = (-sin phi, cos phi, 0)
        tan = torch.stack([-phi.sin(), phi.cos(), torch.zeros_like(phi)])
        assert float((hits.tangent[k][:, away] * tan[:, away]).sum(0).min()) > 0.99


def test_plane_mesh_gives_the_planar_samples_gbuffer_and_images():
    views = [View.collocated(c, 5.0) for c in _cams()[:1]] + \
        [View(PerspectiveCamera((-1.0, 2.0, 2.5), resolution=48), (PointLight((1.0, 1.0, 2.0), 3.0),))]
    gp = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float64)
    gm = GBuffer.build(views, Mesh.plane(2.0), dtype=torch.float64)
    both = gp.mask & gm.mask
    assert int((gp.mask != gm.mask).sum()) <= 4 and int(both.sum()) > 1000     # edge pixels may differ
    for f in ("position", "normal", "tangent", "bitangent", "view_dir"):
        a, b = getattr(gp, f).expand_as(getattr(gm, f)), getattr(gm, f)
        assert float((a - b).abs().permute(1, 0, 2, 3)[:, both].max()) < 1e-5, f
    assert float((gp.uv - gm.uv)[both].abs().max()) < 1e-5
    maps = SVBRDF(torch.rand(3, 16, 16, dtype=torch.float64), torch.rand(1, 16, 16, dtype=torch.float64) * .8 + .1,
                  torch.full((3, 1, 1), 0.04, dtype=torch.float64),
                  torch.nn.functional.normalize(torch.rand(3, 16, 16, dtype=torch.float64) * 0.4 +
                                                torch.tensor([-0.2, -0.2, 1.0], dtype=torch.float64)[:, None, None], dim=0))
    ip, im = render(maps, views, PlanarSample(2.0))[0], render(maps, views, Mesh.plane(2.0))[0]
    assert float((ip - im)[both].abs().max() / ip[both].abs().max()) < 1e-4    # normal map included


def _box_shadow(q, light, lo, hi):
    """Slab test: does the segment q -> light cross the box [lo, hi]? (q [N, 3])"""
    d = light[None] - q
    with torch.no_grad():
        t0 = (lo[None] - q) / d
        t1 = (hi[None] - q) / d
    tmin = torch.minimum(t0, t1).amax(1)
    tmax = torch.maximum(t0, t1).amin(1)
    return (tmax >= tmin.clamp_min(1e-6)) & (tmin < 1)


def test_block_casts_the_analytic_shadow_on_the_ground():
    mesh = Mesh.block_on_plane(2.0, (0.5, 0.5, 0.5))
    light = PointLight((2.5, 0.4, 1.2), 10.0)
    view = View(PerspectiveCamera((0.0, -0.5, 4.0), resolution=64, fov=40), (light,))
    g = GBuffer.build([view], mesh, dtype=torch.float64)
    pos = g.position[0].permute(1, 2, 0)
    ground = g.mask[0] & (pos[..., 2].abs() < 1e-6)
    q = pos[ground]
    expect = _box_shadow(q, torch.tensor(light.position, dtype=torch.float64),
                         torch.tensor([-0.25, -0.25, 0.0], dtype=torch.float64),
                         torch.tensor([0.25, 0.25, 0.5], dtype=torch.float64))
    lit = g.light_scale[0, 0, 0][ground] > 0
    assert int(expect.sum()) > 50 and int((~expect).sum()) > 500
    # exact away from the shadow's edge: a pixel's hit point near the boundary may go either way in float32
    assert int((lit == expect).sum()) <= max(3, int(0.01 * len(q)))      # lit exactly where not shadowed


def test_mesh_gbuffers_are_cached_and_rectified_cameras_refused():
    mesh = Mesh.sphere(rings=16, segments=32)
    views = (View.collocated(_cams()[0]),)
    assert GBUFFERS.get(views, mesh) is GBUFFERS.get(views, Mesh.sphere(rings=16, segments=32))
    with pytest.raises(InputError, match="cannot look at a mesh"):
        GBuffer.build([View.collocated(RectifiedCamera((0, 0, 3.0), 8))], mesh)


def test_light_stage_views_share_their_cameras_rays():
    """Every camera with every light: the rays of a camera are cast once; each view gets its own light's
    shadows, as when built alone."""
    from bayes_brdf.render import hemisphere_directions, light_stage_views
    mesh = Mesh.block_on_plane()
    views = light_stage_views(hemisphere_directions(2), hemisphere_directions(3, "sobol", max_zenith=75), 4.0, 5.0,
                              resolution=24)
    g = GBuffer.build(views, mesh, dtype=torch.float64)
    for k in (0, 4):
        one = GBuffer.build([views[k]], mesh, dtype=torch.float64)
        for f in ("position", "normal", "light_scale", "uv"):
            torch.testing.assert_close(getattr(g, f)[k:k + 1], getattr(one, f))
    assert not torch.equal(g.light_scale[0], g.light_scale[1])             # same camera, other light


# ---------------------------------------------------------------- winding against the vertex normals
def _rewound(mesh: Mesh) -> Mesh:
    """The same surface with every face wound the other way (geometric normals flipped, vertex normals kept)."""
    return Mesh(mesh.vertices, mesh.faces[:, ::-1], mesh.uv, mesh.normals, name=mesh.name + "_rewound")


def _plate_views():
    """A collocated flash from above, one from an oblique side above, and one from below the plate."""
    cams = [PerspectiveCamera((0.0, 0.3, 4.0), resolution=32, fov=40),
            PerspectiveCamera((2.0, -1.0, 2.5), up=(0, 0, 1), resolution=32, fov=40),
            PerspectiveCamera((0.2, 0.0, -3.0), up=(0, 1, 0), resolution=32, fov=40)]
    return [View.collocated(c, 5.0) for c in cams]


def test_faces_wound_against_the_vertex_normals_are_shaded_by_the_normals():
    """A plate whose faces wind downward (-z by the right-hand rule) while its vertex normals say +z, seen from
    above under a flash: shading follows the normals (up, towards the camera), not black; as the plate wound right."""
    good = Mesh.plane(2.0)
    bad = _rewound(good)
    assert np.all(bad.face_normals[:, 2] < 0) and np.all(bad.normals[:, 2] > 0)
    views = _plate_views()
    gb, gg = GBuffer.build(views, bad, dtype=torch.float64), GBuffer.build(views, good, dtype=torch.float64)
    assert torch.equal(gb.mask, gg.mask) and int(gb.mask[0].sum()) > 300
    above = gb.mask[0]
    assert float(gb.normal[0, 2][above].min()) > 0.999                  # up, towards the camera
    hits = bad.intersect([v.camera for v in views])
    assert float(hits.geometric_normal[0, 2][above].min()) > 0.999      # oriented by the normals, then two-sided
    assert float(hits.normal[2, 2][hits.mask[2]].max()) < -0.999         # from below: both flipped to the camera
    for f in ("position", "normal", "tangent", "bitangent", "view_dir", "light_scale"):
        torch.testing.assert_close(getattr(gb, f), getattr(gg, f), rtol=0, atol=1e-6, msg=f)
    maps = SVBRDF.constant(albedo=(0.6, 0.5, 0.4), roughness=0.4, specular=0.04, dtype=torch.float64)
    ib, ig = render(maps, views, bad), render(maps, views, good)
    m = gg.mask[None, ..., None].expand_as(ig)                           # images [1, V, H, W, 3]
    assert float(ig[m].min()) > 0 and float(ib[m].min()) > 0                # lit everywhere on the plate
    torch.testing.assert_close(ib, ig, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("ext", ["obj", "ply", "glb"])
def test_a_file_wound_against_its_normals_keeps_them_and_renders_as_the_right_winding(tmp_path, ext):
    """Scans and exports often wind faces against their normals: loading keeps the file's normals (no repair), and
    the render is the one of the plate wound right."""
    good = Mesh.plane(2.0)
    path = tmp_path / f"plate.{ext}"
    _rewound(good).to_trimesh().export(str(path))
    m = Mesh.load(path)
    assert m.meta["normals_source"] == "file" and m.meta["uv_source"] == "file"
    assert np.all(m.face_normals[:, 2] < 0) and np.allclose(m.normals, (0.0, 0.0, 1.0))
    views = _plate_views()
    maps = SVBRDF.constant(albedo=(0.6, 0.5, 0.4), roughness=0.4, specular=0.04, dtype=torch.float64)
    torch.testing.assert_close(render(maps, views, m), render(maps, views, good), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("shape", ["block_on_plane", "bowl"])
def test_rewinding_a_closed_or_shadowing_mesh_changes_no_gbuffer(shape):
    """Every face wound the other way (vertex normals kept): the same normals, frames and shadows (the shadow rays
    leave on the light's side whatever the winding)."""
    good = getattr(Mesh, shape)() if shape == "block_on_plane" else Mesh.bowl(rings=12, segments=32)
    from bayes_brdf.render import hemisphere_directions, light_stage_views
    views = light_stage_views(hemisphere_directions(2), hemisphere_directions(3, "sobol", max_zenith=75), 4.0, 5.0,
                              resolution=24)
    gb, gg = GBuffer.build(views, _rewound(good), dtype=torch.float64), GBuffer.build(views, good, dtype=torch.float64)
    assert torch.equal(gb.mask, gg.mask)
    assert int((gg.light_scale == 0).sum()) > 0                         # some shadows to compare
    for f in ("position", "normal", "tangent", "bitangent", "light_scale", "uv"):
        torch.testing.assert_close(getattr(gb, f), getattr(gg, f), rtol=0, atol=1e-6, msg=f)
