"""The paper's Table 1 as a test: samplers on a 2-D posterior against dense quadrature.

Runs every row (20 runs each, the presets' hyper-parameters and steps) and asserts the
paper's ranking: SPOS beats SGLD and multi-start SGD on both columns, and the
default SPOS is within 1.2x the floor of 16 exact i.i.d. draws. Regenerate the table in the
docs with ``bayes-brdf compare --json docs/table1.json``.
"""
import json
import math

import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.experiments.table1 import Table1Setup, compare, markdown, problem, quadrature
from bayes_brdf.potential import Potential


def test_problem_is_genuinely_ambiguous_and_quadrature_converged():
    coarse, fine = quadrature(Table1Setup(grid=500)), quadrature(Table1Setup(grid=1000))
    assert (fine["var"] >= 0.002).all(), fine["var"]
    torch.testing.assert_close(coarse["mean"], fine["mean"], rtol=2e-3, atol=0)
    torch.testing.assert_close(coarse["var"], fine["var"], rtol=1e-2, atol=0)
    # the observed pixel is what the truth renders to, and the truth is on the posterior's ridge
    model, data = problem(Table1Setup())
    pot = Potential(model, (data,))
    z = pot.to_unconstrained({"albedo": torch.tensor([[0.5]], dtype=torch.float64),
                              "roughness": torch.tensor([[0.5]], dtype=torch.float64)})
    u = pot.energy(z, jacobian=False)
    # -log f at the truth: zero residual, so only the Laplace normaliser (3 channels) and the prior remain
    assert float(u) == pytest.approx(3 * math.log(2 * 0.01) + math.log(0.95), rel=1e-6)  # y stored as float32


def test_quadrature_resolves_a_posterior_narrower_than_a_cell():
    # two views, a sharp highlight: the roughness std (~1e-4) is a tenth of a cell of the prior's box; the refined
    # grid puts the mass over many cells, and a grid half as fine agrees with it
    setup = Table1Setup(observations=[40.0], albedo=0.7, roughness=0.15)
    coarse, fine = quadrature(Table1Setup(**{**setup.__dict__, "grid": 500})), quadrature(setup)
    std = fine["var"].sqrt()
    assert float(std[1]) > 10 * float(fine["cell"][1]), (std, fine["cell"])
    assert int((fine["weights"] > 1e-4 * fine["weights"].max()).sum()) > 1000
    torch.testing.assert_close(coarse["mean"], fine["mean"], rtol=1e-3, atol=0)
    torch.testing.assert_close(coarse["var"], fine["var"], rtol=2e-2, atol=0)
    assert float(fine["mean"][1]) == pytest.approx(0.15, abs=3 * float(std[1]))


@pytest.mark.slow
def test_table1_ranking_and_floor():
    table = compare(Table1Setup(), runs=20, particles=16, steps={"emcee": 500})   # emcee: ~5 s a run
    print("\n" + markdown(table))
    spos, iid = table["spos"], table["iid"]
    for col in ("mse_mean", "mse_var"):
        assert spos[col] < table["sgld"][col], col
        assert spos[col] < table["multistart_sgd"][col], col
        assert spos[col] <= 1.2 * iid[col], (col, spos[col], iid[col])
    for name in ("spos", "svgd", "sgld", "multistart_sgd"):
        assert table[name]["evaluations"] == 16 * table[name]["steps"]
    assert set(table) == {"_truth", "iid", "spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts"}


def test_compare_cli_writes_json(tmp_path, capsys):
    out = tmp_path / "t.json"
    rc = main(["compare", "--runs", "2", "--steps", "30", "--samplers", "spos,sgld", "--grid", "200",
               "--param", "spos.beta=10", "--json", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    assert set(d) == {"iid", "spos", "sgld", "_truth"}
    assert set(d["spos"]) >= {"mse_mean", "mse_var", "seconds"}
    assert "| spos |" in capsys.readouterr().out


@pytest.mark.parametrize("argv, msg", [
    (["compare", "--albedo", "2"], "--albedo must be in [0, 1]"),
    (["compare", "--samplers", "nope", "--runs", "1", "--grid", "50"], "no sampler preset 'nope'"),
    (["compare", "--param", "beta=3", "--runs", "1"], "name the sampler"),
    (["compare", "--angle", "95"], "angles must be in"),
])
def test_compare_bad_input_is_one_line(argv, msg, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1
