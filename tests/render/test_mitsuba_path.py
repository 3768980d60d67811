"""Mitsuba's path tracer as a second renderer (``render_reference(..., integrator="path")`` and ``bayes-brdf
render --integrator path``): captures from a renderer that is not our forward model.

What needs no trust in either renderer: with ``max_depth = 2`` a path tracer is direct light, so it equals the
direct reference; on a convex mesh no light bounces twice, so any depth equals it; on concave meshes (the bowl,
a block on a plane) light that bounced adds and never takes away.
"""
import json

import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.errors import InputError
from bayes_brdf.render import SVBRDF, collocated_views
from bayes_brdf.render.environment import studio
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.mitsuba_reference import check_views, render_reference
from bayes_brdf.render.views import View

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.needs_llvm

MAPS = SVBRDF.constant(albedo=0.6, roughness=0.4).to(torch.float64)


def test_depth_two_is_direct_light_and_a_convex_mesh_has_no_interreflections():
    block = Mesh.block_on_plane()
    views = check_views(block, "block_on_plane", 24)[:2]
    direct = render_reference(MAPS, views, block)
    # point lights: one exact emitter sample per vertex, and depth 2 ends there
    assert torch.equal(render_reference(MAPS, views, block, integrator="path", max_depth=2, spp=1), direct)
    # under an environment both are Monte Carlo: the same within their noise
    env = studio(16)
    ve = [View(v.camera, (env,), v.name) for v in views]
    d, p = (render_reference(MAPS, ve, block, spp=256, integrator=i, max_depth=2) for i in ("direct", "path"))
    assert float(p.mean()) == pytest.approx(float(d.mean()), rel=0.01)
    # a sphere is convex: every path that leaves it escapes, so depth 8 adds nothing (measured: one pixel of
    # 1 728 gains 6e-5 of its value, a direction above its smooth shading normal but below its facet)
    sphere = Mesh.sphere()
    vs = collocated_views(3, 4.0, resolution=24, power=20.0)
    path, direct = render_reference(MAPS, vs, sphere, integrator="path", spp=4), render_reference(MAPS, vs, sphere)
    assert float((path - direct).abs().max()) < 1e-4 * float(direct.max())


@pytest.mark.parametrize("shape", ["bowl", "block_on_plane"])
def test_light_that_bounced_adds_on_concave_meshes(shape):
    mesh = Mesh.bowl() if shape == "bowl" else Mesh.block_on_plane()
    views = check_views(mesh, shape, 24)[:2]
    direct = render_reference(MAPS, views, mesh)
    path = render_reference(MAPS, views, mesh, integrator="path", spp=64)
    assert float((path - direct).min()) >= -1e-6          # never darker: point lights' direct part is exact
    assert float(path.mean()) > 1.02 * float(direct.mean()), (float(path.mean()), float(direct.mean()))


def test_bad_integrator_options_are_one_line():
    with pytest.raises(InputError, match="integrator"):
        render_reference(MAPS, collocated_views(1, 4.0, resolution=8), Mesh.sphere(), integrator="bdpt")
    with pytest.raises(InputError, match="max_depth"):
        render_reference(MAPS, collocated_views(1, 4.0, resolution=8), Mesh.sphere(), integrator="path",
                         max_depth=1)


def test_cli_renders_a_path_traced_capture_that_fits(tmp_path, capsys):
    cap = tmp_path / "cap"
    assert main(["render", "wood", "--mesh", "bowl", "--views", "fibonacci:5", "--resolution", "24",
                 "--integrator", "path", "--spp", "16", "--out", str(cap)]) == 0
    out = capsys.readouterr().out
    assert "path integrator (16 spp, max depth 8;" in out and "s per view" in out
    ours = tmp_path / "ours"
    assert main(["render", "wood", "--mesh", "bowl", "--views", "fibonacci:5", "--resolution", "24",
                 "--out", str(ours)]) == 0
    from bayes_brdf.io import load_capture
    a, b = load_capture(cap), load_capture(ours)
    assert a.images.shape == b.images.shape and float(a.images.mean()) > float(b.images.mean())   # interreflections
    fit = tmp_path / "fit"
    assert main(["fit", str(cap), "--holdout", "4", "--steps", "40", "--particles", "6", "--out", str(fit)]) == 0
    s = json.loads((fit / "summary.json").read_text())
    assert s["heldout"]["pixels"] > 0
    # the plane, without --mesh: perspective views of the two-triangle square
    assert main(["render", "marble", "--views", "fibonacci:2", "--resolution", "16", "--integrator", "direct",
                 "--out", str(tmp_path / "plane")]) == 0
    capsys.readouterr()
    for bad, words in ((["--spp", "8"], "--integrator path"), (["--integrator", "path", "--camera", "rectified"],
                                                               "perspective"),
                       (["--integrator", "direct", "--max-depth", "3"], "--max-depth")):
        assert main(["render", "marble", "--views", "fibonacci:2", "--resolution", "8", *bad,
                     "--out", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, (bad, err)
