"""View types and configuration generators."""
import math

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.render import (PerspectiveCamera, PointLight, RectifiedCamera, View, collocated_views,
                               hemisphere_directions, light_stage_views, orbit_views)


@pytest.mark.parametrize("method", ["fibonacci", "sobol", "random"])
def test_hemisphere_directions_are_unit_upper_and_within_zenith(method):
    d = hemisphere_directions(500, method, max_zenith=60, seed=3)
    torch.testing.assert_close(d.norm(dim=1), torch.ones(500, dtype=torch.float64))
    assert d[:, 2].min() >= math.cos(math.radians(60)) - 1e-12
    # uniform in solid angle: mean cos(theta) over the cap is (1 + cos max) / 2
    assert float(d[:, 2].mean()) == pytest.approx((1 + 0.5) / 2, abs=0.03)
    # and uniform in azimuth: the mean horizontal direction is near zero
    assert float(d[:, :2].mean(0).norm()) < 0.06


def test_low_discrepancy_sets_are_deterministic_by_seed():
    assert torch.equal(hemisphere_directions(64, "fibonacci"), hemisphere_directions(64, "fibonacci"))
    assert torch.equal(hemisphere_directions(64, "sobol", seed=1), hemisphere_directions(64, "sobol", seed=1))
    assert not torch.equal(hemisphere_directions(64, "sobol", seed=1), hemisphere_directions(64, "sobol", seed=2))


def test_collocated_views_put_the_flash_at_the_camera_and_look_at_the_target():
    vs = collocated_views(7, radius=20.0, method="sobol", camera="perspective", resolution=(16, 24), power=1500.0)
    assert len(vs) == 7
    for v in vs:
        assert v.lights[0].position == v.camera.position
        assert math.dist(v.camera.position, (0, 0, 0)) == pytest.approx(20.0)
        assert v.resolution == (16, 24) and v.lights[0].power == (1500.0,) * 3
    rect = collocated_views(3, radius=10.0, camera="rectified", resolution=32)
    assert all(isinstance(v.camera, RectifiedCamera) for v in rect)


def test_orbit_and_light_stage():
    o = orbit_views(4, 2.0, zenith=45)
    z = [v.camera.position[2] for v in o]
    assert z == pytest.approx([math.sqrt(2)] * 4)
    ls = light_stage_views(hemisphere_directions(3), hemisphere_directions(5, "sobol"), 3.0, 6.0)
    assert len(ls) == 15
    assert ls[0].camera == ls[4].camera and ls[0].lights != ls[1].lights  # camera-major ordering
    assert all(math.dist(v.lights[0].position, (0, 0, 0)) == pytest.approx(6.0) for v in ls)


def test_view_serialisation_round_trip():
    vs = [View(PerspectiveCamera((1, 2, 3.0), fov=30, resolution=(8, 12)), (PointLight((0, 0, 5.0), (1, 2, 3.0)),), "a"),
          View.collocated(RectifiedCamera((0.5, 0, 9.0), 16), 1500, falloff=False, name="b")]
    for v in vs:
        assert View.from_dict(v.to_dict()) == v


@pytest.mark.parametrize("bad", [
    lambda: PerspectiveCamera((0, 0, float("nan"))),
    lambda: PerspectiveCamera((0, 0, 3.0), fov=190),
    lambda: PointLight((0, 0, 1.0), -1.0),
    lambda: hemisphere_directions(10, "grid"),
    lambda: View.from_dict({"camera": {"type": "perspective"}, "lights": []}),
    lambda: collocated_views(3, 2.0, camera="fisheye"),
])
def test_bad_view_arguments_are_input_errors(bad):
    with pytest.raises(InputError):
        bad()
