"""Preset folders: found from the source tree, user paths accepted, bad input is one line."""
import pytest

from bayes_brdf.errors import InputError
from bayes_brdf.presets import list_presets, load_preset


def test_user_preset_path_and_errors(tmp_path):
    p = tmp_path / "mine.toml"
    p.write_text('name = "mine"\nsteps = 10\n')
    assert load_preset("samplers", p) == {"name": "mine", "steps": 10}
    with pytest.raises(InputError, match="no sampler preset 'nope'"):
        load_preset("samplers", "nope")
    bad = tmp_path / "bad.toml"
    bad.write_text("steps = = 1")
    with pytest.raises(InputError, match="bad.toml"):
        load_preset("samplers", bad)
    with pytest.raises(InputError):
        list_presets("priors")


def test_every_shipped_preset_loads():
    for kind in ("models", "samplers"):
        for name in list_presets(kind):
            assert isinstance(load_preset(kind, name), dict)


def test_every_sampler_and_model_preset_builds():
    from bayes_brdf.models.material import from_preset
    from bayes_brdf.samplers import make_sampler
    for name in list_presets("samplers"):
        sampler, cfg = make_sampler(name)
        assert cfg.particles >= 1 and cfg.steps >= 1
    for name in list_presets("models"):
        assert callable(from_preset(load_preset("models", name)))
