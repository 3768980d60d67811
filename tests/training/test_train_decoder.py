"""Training the decoder: deterministic by seed, and an interrupted run resumes to the same weights."""
import json

import pytest
import torch

from bayes_brdf.models.decoder_file import load_decoder, read_header
from bayes_brdf.models.stylegan import PRESETS, GeneratorConfig
from bayes_brdf.training import TrainConfig, train_decoder
import bayes_brdf.training.train as train_mod

TINY = GeneratorConfig(resolution=16, w_dim=16, z_dim=16, mapping_layers=2, fmaps_base=128, fmaps_max=16)


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setitem(PRESETS, "tiny", TINY)
    return TrainConfig(preset="tiny", steps=6, batch=3, base_materials=6, threads=1)


def _weights(path):
    g = load_decoder(path)
    return {k: v.clone() for k, v in g.state_dict().items()}


def test_same_seed_same_weights_and_a_header_that_says_how(tiny, tmp_path):
    a = train_decoder(tiny, tmp_path / "a.safetensors", log=lambda *_: None)
    train_decoder(tiny, tmp_path / "b.safetensors", log=lambda *_: None)
    wa, wb = _weights(tmp_path / "a.safetensors"), _weights(tmp_path / "b.safetensors")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    head = read_header(tmp_path / "a.safetensors")
    assert head["config"]["resolution"] == 16 and head["training"]["method"] == "vae"
    assert head["training"]["config"]["seed"] == 0 and a["steps"] == 6
    curve = json.loads((tmp_path / "a.safetensors.curve.json").read_text())
    assert [c["step"] for c in curve] == list(range(1, 7)) and all(c["l1"] > 0 for c in curve)
    other = TrainConfig(**{**tiny.__dict__, "seed": 1})
    train_decoder(other, tmp_path / "c.safetensors", log=lambda *_: None)
    wc = _weights(tmp_path / "c.safetensors")
    assert not torch.equal(wa["synthesis.const"], wc["synthesis.const"])


def test_an_interrupted_run_resumes_to_the_same_weights(tiny, tmp_path, monkeypatch):
    full = tmp_path / "full.safetensors"
    train_decoder(tiny, full, log=lambda *_: None)
    real, calls = train_mod.augmented_batch, {"n": 0}

    def stop_at_fifth(*a, **k):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real(*a, **k)

    part = tmp_path / "part.safetensors"
    monkeypatch.setattr(train_mod, "augmented_batch", stop_at_fifth)
    with pytest.raises(KeyboardInterrupt):
        train_decoder(tiny, part, checkpoint_every=2, log=lambda *_: None)
    assert (tmp_path / "part.safetensors.ckpt").is_file() and not part.exists()
    monkeypatch.setattr(train_mod, "augmented_batch", real)
    lines = []
    train_decoder(tiny, part, checkpoint_every=2, log=lines.append)
    assert any("resumed from step 4" in s for s in lines)
    wf, wp = _weights(full), _weights(part)
    assert all(torch.equal(wf[k], wp[k]) for k in wf)
    assert not (tmp_path / "part.safetensors.ckpt").exists()
