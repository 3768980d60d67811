"""The Scene type: the plane's hits through the geometry protocol, saving scenes, posteriors that carry them."""
import torch

from bayes_brdf.observations import Observations
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import PerspectiveCamera, PlanarSample, PointLight, RectifiedCamera, View, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.scene import Scene, surface_from_state, surface_state


def test_plane_hits_carry_a_frame_along_texture_axes_and_grid_sample_uv():
    cams = [PerspectiveCamera((0.3, -0.2, 3.0), resolution=12), PerspectiveCamera((-1.0, 0.5, 2.0), resolution=12)]
    s = PlanarSample(2.0)
    hits = s.intersect(cams)
    assert hits.position.shape == (2, 3, 12, 12) and hits.mask.shape == (2, 12, 12) and not hits.aligned
    for f, e in ((hits.tangent, (1.0, 0, 0)), (hits.bitangent, (0, 1.0, 0)), (hits.normal, (0, 0, 1.0))):
        torch.testing.assert_close(f, torch.tensor(e, dtype=torch.float64)[None, :, None, None].expand(2, 3, 12, 12))
    m = hits.mask
    torch.testing.assert_close(hits.uv[..., 0][m], hits.position[:, 0][m])          # size 2: uv x = x
    torch.testing.assert_close(hits.uv[..., 1][m], -hits.position[:, 1][m])         # rows from +y
    assert s.occluded(hits, torch.zeros(2, 1, 3)) is None


def test_light_incident_terms_are_what_the_gbuffer_holds():
    light = PointLight((0.5, 0.2, 3.0), (3.0, 2.0, 1.0))
    view = View(RectifiedCamera((0, 0, 4.0), 6), (light,))
    g = GBuffer.build([view], PlanarSample(2.0), dtype=torch.float64)
    hits = PlanarSample(2.0).intersect([view.camera])
    inc = light.incident(hits.position[0], hits.mask[0])
    torch.testing.assert_close(g.light_scale[0, 0], inc.scale)
    torch.testing.assert_close(g.light_dir[0, 0], inc.direction)
    shadow = torch.zeros(6, 6, dtype=torch.bool)
    shadow[:, :3] = True                               # a shadow zeroes exactly its pixels
    sc = light.incident(hits.position[0], hits.mask[0], visible=~shadow).scale
    assert bool((sc[:, shadow] == 0).all()) and bool((sc[:, ~shadow] == inc.scale[:, ~shadow]).all())


def test_scene_round_trips_and_observations_carry_it():
    views = collocated_views(3, 3.0, resolution=8, power=(1.0, 2.0, 3.0))
    obs = Observations(views, torch.zeros(3, 8, 8, 3), PlanarSample(4.5, "endpoints"))
    sc = obs.scene
    assert sc.surface == obs.surface and list(sc.views) == views and len(sc.lights) == 3
    meta, tensors = sc.state()
    assert meta["surface"] == {"type": "plane", "size": 4.5, "grid": "endpoints"} and tensors == {}
    assert Scene.from_state(meta, tensors) == sc
    assert surface_from_state({"size": 2.0, "grid": "centers"}) == PlanarSample(2.0)   # files from before scenes


def test_posterior_file_carries_its_surface(tmp_path):
    post = Posterior({"roughness": torch.rand(4, 1)}, torch.rand(4), surface=PlanarSample(6.848))
    back = Posterior.load(post.save(tmp_path / "p.safetensors"))
    assert back.surface == PlanarSample(6.848)
    assert back.meta["surface"] == surface_state(PlanarSample(6.848))[0]
