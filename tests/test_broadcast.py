"""bayes_brdf.broadcast.broadcast_shapes follows torch's (numpy's) rule, without importing torch._refs."""
import subprocess
import sys

import pytest
import torch

from bayes_brdf.broadcast import broadcast_shapes

CASES = [((), ()), ((3,), ()), ((2,), (3, 1), (1, 1, 1)), ((20, 1, 4), (5, 1)), ((0,), (1,)), ((4, 1), (1, 0)),
         ((1, 3, 64, 64), (20, 3, 64, 64), (64,))]


@pytest.mark.parametrize("shapes", CASES)
def test_broadcast_shapes_agrees_with_torch(shapes):
    assert broadcast_shapes(*shapes) == torch.broadcast_shapes(*shapes)


def test_shapes_that_do_not_broadcast_raise():
    with pytest.raises(ValueError, match="do not broadcast"):
        broadcast_shapes((2, 3), (4, 3))


def test_a_potential_is_built_without_sympy():
    """Building a model's potential and its energy must not import sympy (half a second of every command)."""
    code = ("import sys, torch, bayes_brdf as bb\n"
            "from bayes_brdf.potential import Potential\n"
            "from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views\n"
            "from bayes_brdf.render.shade import render\n"
            "views = collocated_views(3, 3.0, camera='rectified', resolution=8)\n"
            "obs = bb.Observations(views, render(SVBRDF.constant(0.5, 0.3), views, PlanarSample(2.0))[0], "
            "PlanarSample(2.0))\n"
            "from bayes_brdf.models import ModelData\n"
            "pot = Potential(bb.models.per_texel(8), (ModelData.from_observations(obs),))\n"
            "pot.value_and_grad(pot.init(4, seed=0))\n"
            "print('sympy' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
