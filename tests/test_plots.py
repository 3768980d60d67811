"""The figures (bayes_brdf.plots): the colormap, value maps as EXR + PNG, panel grids and line plots, and the
rule that plots owns matplotlib and that render / models / samplers never import it."""
import ast
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.errors import InputError
from bayes_brdf.io import read_image
from bayes_brdf.plots import CMAP, colorize, line_plot, map_panel, panel_grid, write_map

PACKAGE = Path(__file__).resolve().parents[1] / "bayes_brdf"


def test_colorize_uses_the_colormap_and_clips():
    import matplotlib
    cm = matplotlib.colormaps[CMAP]
    x = torch.tensor([[0.0, 0.5, 1.0], [2.0, -1.0, float("nan")]])
    c = colorize(x, vmin=0.0, vmax=1.0)
    assert c.shape == (2, 3, 3) and c.dtype == np.uint8
    ref = (np.array([cm(0.0), cm(0.5), cm(1.0), cm(1.0), cm(0.0), cm(0.0)])[:, :3] * 255 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(c.reshape(-1, 3), ref)
    # default vmax: the 99th percentile
    v = np.linspace(0, 1, 101)
    np.testing.assert_array_equal(colorize(v[None]), colorize(v[None], vmax=float(np.percentile(v, 99))))


@pytest.mark.parametrize("shape", [(12, 10), (12, 10, 3), (3, 12, 10), (12, 10, 2), (2, 12, 10)])
def test_write_map_writes_exact_exr_and_a_colour_png(tmp_path, shape):
    g = torch.Generator().manual_seed(1)
    v = torch.rand(*shape, generator=g) * 0.3
    png = write_map(tmp_path / "sub" / "std_map", v, title="std", unit="radiance")
    assert png == tmp_path / "sub" / "std_map.png" and png.is_file()
    back = read_image(tmp_path / "sub" / "std_map.exr")
    hwc = v.movedim(0, -1) if shape[0] in (2, 3) else v
    hwc = hwc[..., None] if hwc.dim() == 2 else hwc
    if hwc.shape[-1] == 2:                                               # two channels: R, G and B = 0
        hwc = torch.cat([hwc, torch.zeros(12, 10, 1)], -1)
    assert back.shape == (12, 10, 3)
    np.testing.assert_array_equal(back, np.broadcast_to(hwc.numpy(), (12, 10, 3)))
    im = Image.open(png)
    assert im.mode in ("RGB", "RGBA")
    a = np.asarray(im.convert("RGB"))
    assert a.shape[0] > 50 and a.shape[1] > 50
    colours = np.unique(a.reshape(-1, 3), axis=0)
    assert len(colours) > 20                                             # the map and its colour bar
    # the inferno colours of the map show up in the figure (a dark and a bright one)
    cm = (np.array([colorize(np.array([[0.0, 1.0]]), 0.0, 1.0)])[0, 0]).astype(int)
    dist = lambda col: np.abs(a.astype(int) - col).sum(-1).min()        # noqa: E731
    assert dist(cm[0]) <= 6 and dist(cm[1]) <= 6
    # png only
    write_map(tmp_path / "only_png", v, exr=False)
    assert (tmp_path / "only_png.png").is_file() and not (tmp_path / "only_png.exr").exists()


def test_write_map_refuses_a_stack_of_maps_in_one_line(tmp_path):
    with pytest.raises(InputError, match=r"write_map: a map is .* got \(12, 10, 5\)"):
        write_map(tmp_path / "stack", torch.zeros(12, 10, 5))


def _png(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def test_panel_grid_shares_one_range_and_wraps_a_flat_list(tmp_path):
    g = torch.Generator().manual_seed(0)
    small, big = torch.rand(8, 8, generator=g) * 0.1, torch.rand(8, 8, generator=g)
    shared = panel_grid(tmp_path / "shared.png", [map_panel(small, "small"), map_panel(big, "big")], share=True,
                        style="compact")
    explicit = panel_grid(tmp_path / "explicit.png", [map_panel(small, "small", vmax=float(np.percentile(big, 99))),
                                                      map_panel(big, "big", vmax=float(np.percentile(big, 99)))],
                          style="compact")
    np.testing.assert_array_equal(_png(shared), _png(explicit))
    own = panel_grid(tmp_path / "own.png", [map_panel(small, "small"), map_panel(big, "big")], style="compact")
    assert not np.array_equal(_png(own), _png(shared))
    # a flat list wraps every ncols: four panels in two rows of two, as the same panels given as rows
    panels = [map_panel(big, f"p{i}", vmax=1.0) for i in range(4)]
    flat = panel_grid(tmp_path / "flat.png", panels, ncols=2, style="compact")
    rows = panel_grid(tmp_path / "rows.png", [panels[:2], panels[2:]], style="compact")
    np.testing.assert_array_equal(_png(flat), _png(rows))


def test_line_plot_draws_a_spread_as_bars_or_a_band(tmp_path):
    series = {"a": ([1, 2, 3], [0.3, 0.2, 0.1], [0.05, 0.05, 0.05])}
    plain = _png(line_plot(tmp_path / "plain.png", {"a": series["a"][:2]}, xlabel="x", ylabel="y"))
    bars = _png(line_plot(tmp_path / "bars.png", series, xlabel="x", ylabel="y"))
    band = _png(line_plot(tmp_path / "band.png", series, xlabel="x", ylabel="y", spread="band"))
    assert plain.shape == bars.shape == band.shape
    assert not np.array_equal(plain, bars) and not np.array_equal(bars, band)
    report = _png(line_plot(tmp_path / "report.png", series, xlabel="x", ylabel="y", spread="band", style="report"))
    assert report.shape[1] > band.shape[1]                               # the report's charts are larger


def test_the_decoder_figures_of_the_committed_weights(tmp_path):
    from bayes_brdf.plots import decoder_curve, decoder_samples
    from bayes_brdf.training.train import decoded_samples, read_curve

    weights = PACKAGE.parent / "models" / "latent_decoder_64.safetensors"
    curve = read_curve(weights)
    assert curve[0]["step"] == 1 and {"l1", "kl", "seconds"} <= set(curve[-1])
    rows = decoded_samples(weights, n=2)
    assert [name for name, _ in rows] == ["albedo", "normal", "roughness", "flash render"]
    assert all(t.shape == (2, 64, 64, 3) for _, t in rows)
    for png in (decoder_curve(curve, tmp_path / "curve.png"), decoder_samples(rows, tmp_path / "samples.png")):
        assert _png(png).shape[0] > 100


def _imports(path: Path) -> set[str]:
    """Absolute names of the modules ``path`` imports (relative imports resolved inside the package)."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    pkg = parts[:-1]                                                     # the package the module is in
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = list(pkg[:len(pkg) - node.level + 1]) if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
    return out


def test_plots_owns_matplotlib_and_the_core_never_imports_plots():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        names = _imports(path)
        if rel.parts[0] != "plots":
            assert not any(n == "matplotlib" or n.startswith("matplotlib.") for n in names), \
                f"{rel} imports matplotlib: figures belong in bayes_brdf.plots"
        if rel.parts[0] in ("render", "models", "samplers"):
            assert not any(n == "bayes_brdf.plots" or n.startswith("bayes_brdf.plots.") for n in names), \
                f"{rel} imports bayes_brdf.plots"
