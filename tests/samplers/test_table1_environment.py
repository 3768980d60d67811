"""Table 1 under a known environment light: a posterior with an exact answer (dense 2-D quadrature of the
same model) sampled by every sampler.

Two cases with a known, informative answer (the one-pixel, environment-only problem is not one: its
ridge has a constant cross-section, so the roughness marginal is flat and any sampler matches it):

- ``env2``: the built-in studio alone, two pixels (cameras at 20 and 0 degrees; the first mirrors the
  softbox): a narrow posterior, roughness std ~0.05, albedo std ~0.014;
- ``env_flash``: the studio plus the collocated flash, one pixel at 0 degrees: a wide curved ridge.
"""
import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.experiments.table1 import Table1Setup, compare, environment_of, markdown, problem, quadrature
from bayes_brdf.render.environment import studio

CASES = {"env2": dict(lighting="environment", angle=20.0, observations=[0.0]),
         "env_flash": dict(lighting="environment+flash", angle=0.0)}


@pytest.mark.parametrize("case", sorted(CASES))
def test_environment_posterior_quadrature_converged_and_informative(case):
    coarse = quadrature(Table1Setup(**CASES[case], grid=500))
    fine = quadrature(Table1Setup(**CASES[case], grid=1000))
    torch.testing.assert_close(coarse["mean"], fine["mean"], rtol=2e-3, atol=0)
    torch.testing.assert_close(coarse["var"], fine["var"], rtol=1e-2, atol=0)
    # informative: the prior box's variances are 1/12 (albedo) and 0.95^2/12 (roughness)
    assert (fine["var"] < 0.06).all(), fine["var"]
    assert (fine["var"] > 1e-4).all(), fine["var"]
    # the truth (0.5, 0.5) is within three posterior standard deviations of the mean
    assert ((fine["mean"] - 0.5).abs() < 3 * fine["var"].sqrt()).all(), (fine["mean"], fine["var"])


def test_environment_pixel_is_lit_by_the_studio_and_differs_from_the_flash():
    env, flash = Table1Setup(lighting="environment", angle=20.0), Table1Setup(angle=20.0)
    (_, d_env), (_, d_flash) = problem(env), problem(flash)
    y_env, y_flash = d_env.images, d_flash.images
    assert torch.isfinite(y_env).all() and (y_env > 0).all()
    assert not torch.allclose(y_env, y_flash)
    # a glossy pixel seen by the camera at 20 degrees mirrors the softbox: brighter than the camera at 0
    # degrees', which mirrors the dim sky
    (_, d20), (_, d0) = (problem(Table1Setup(lighting="environment", angle=a, roughness=0.1)) for a in (20.0, 0.0))
    assert float(d20.images.mean()) > 1.5 * float(d0.images.mean())
    # the default environment is the studio turned to -x, the same light as a user building it by hand
    built = studio(azimuth_deg=180.0)
    got = environment_of(env)
    assert torch.equal(got.radiance, built.radiance) and got.to_world == built.to_world


def test_compare_cli_environment_bad_input(tmp_path, capsys):
    assert main(["compare", "--env", str(tmp_path / "none.exr"), "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert "--lighting environment" in err and err.count("\n") == 1
    assert main(["compare", "--lighting", "environment", "--env", str(tmp_path / "none.exr"), "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert "environment map not found" in err and err.count("\n") == 1


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_samplers_under_environment_light_against_quadrature(case):
    # 10 runs each; emcee gets its 500 steps (its preset is longer); every sampler of the registry runs
    table = compare(Table1Setup(**CASES[case], grid=1000), runs=10, particles=16, steps={"emcee": 500})
    print("\n" + markdown(table))
    iid = table["iid"]
    for name, row in table.items():
        if name.startswith("_"):
            continue
        assert all(torch.isfinite(torch.tensor(float(row[c]))) for c in ("mse_mean", "mse_var")), name
    # the calibrated default (and SVGD) find the posterior on both columns: within 3x the floor of 16 i.i.d.
    # draws (measured: SPOS 0.6 / 0.8 and 1.0 / 2.1; a 10-run estimate of the floor is itself noisy); emcee's
    # mean too (2.0 and 2.3; its variance runs 6x the floor on the narrow env2 with 500 steps: docs/samplers.md)
    for name, cols in (("spos", ("mse_mean", "mse_var")), ("svgd", ("mse_mean", "mse_var")), ("emcee", ("mse_mean",))):
        for col in cols:
            assert table[name][col] <= 3.0 * iid[col], (name, col, table[name][col], iid[col])
    # SGLD is the worst on the narrow posterior, as in the paper's Table 1
    if case == "env2":
        assert table["sgld"]["mse_mean"] > max(table[n]["mse_mean"] for n in ("spos", "svgd", "emcee"))
