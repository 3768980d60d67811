"""Fig. 6 at a tiny size: both models on both data sets, every number finite, the figure written."""
import json
import math

import pytest

from bayes_brdf.experiments import get


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bayes_brdf.errors.ConvergenceWarning")
def test_fig6_runs_both_models_on_synthetic_and_card_blue(tmp_path):
    res = get("fig6").run(tmp_path, preset="small", seed=0, particles=4, steps=8, per_texel_steps=40,
                          project_steps=30, capture_resolution=32)
    for data in ("synthetic", "capture"):
        for model in ("latent_decoder", "per_texel"):
            r = res[data][model]
            for k in ("pearson", "spearman", "mean_abs_error", "psnr", "mean_image_std", "seconds"):
                assert math.isfinite(r[k]), (data, model, k, r[k])
            assert 0 <= r["coverage"]["50"] <= r["coverage"]["90"] <= 1
            assert set(r["map_std"]) == {"albedo", "roughness"} and r["map_std"]["albedo"] > 0
    assert res["capture"]["latent_decoder"]["held_out"] == [3, 7]
    assert (tmp_path / "fig6.png").stat().st_size > 10000
    saved = json.loads((tmp_path / "fig6.json").read_text())
    want = res["synthetic"]["per_texel"]["mean_abs_error"]
    assert saved["summary"]["synthetic"]["per_texel"]["mae"] == pytest.approx(want)
