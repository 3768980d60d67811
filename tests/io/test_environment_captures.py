"""Environment-lit captures: ``transforms.json`` lights of type ``environment`` (a map relative to the file, a
scale, a rigid ``to_world`` in the file's world frame), ``lights`` lists at the top level or per frame, the
writer's layout, the observation bundle storing the map, and every bad map or light a one-line error (exit 2
from the command line)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.io import load_capture, load_observations, load_transforms, save_observations, save_transforms
from bayes_brdf.io import write_exr, write_png
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import RectifiedCamera
from bayes_brdf.render.environment import EnvironmentLight, z_up
from bayes_brdf.render.lights import PointLight
from bayes_brdf.render.mesh import UP_AXES, Mesh
from bayes_brdf.render.surface import PlanarSample
from bayes_brdf.render.views import View, collocated_views

from .helpers import raises_one_line

H, W = 6, 8


def _map(seed=0, h=8, w=16):
    return np.random.default_rng(seed).uniform(0.1, 2.0, (h, w, 3)).astype(np.float32)


def _mesh():
    return Mesh.sphere(1.0, center=(0.0, 0.0, 0.5), rings=6, segments=12)


def _images(n, seed=0):
    return torch.rand(n, H, W, 3, generator=torch.Generator().manual_seed(seed)) * 0.9


def _flash_views(n=3, power=5.0):
    return collocated_views(n, radius=4.0, target=(0.0, 0.0, 0.5), resolution=(H, W), fov=40.0, power=power)


def _with(views, *extra, flash=True):
    return [View(v.camera, (v.lights if flash else ()) + tuple(extra), v.name) for v in views]


def _same_lights(got, want):
    """The same lights in the same order: point lights exactly, environments by content (map, scale, to_world)."""
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert a.lights == b.lights, (a.lights, b.lights)
        if b.environment is not None:
            assert torch.equal(a.environment.radiance, b.environment.radiance)


def _rays_close(got, want):
    for a, b in zip(got, want):
        (oa, da), (ob, db) = a.camera.rays(dtype=torch.float64), b.camera.rays(dtype=torch.float64)
        assert torch.allclose(oa, ob, atol=1e-9) and torch.allclose(da, db, atol=1e-9)


# ------------------------------------------------------------------ writing and reading back
def test_flash_plus_environment_round_trips_with_one_map_and_a_top_level_lights_list(tmp_path):
    env = EnvironmentLight(_map(), scale=1.5, to_world=z_up(30.0), name="room")
    views = _with(_flash_views(), env)
    obs = Observations(views, _images(3), _mesh())
    save_transforms(obs, tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    assert "light" not in doc and [L["type"] for L in doc["lights"]] == ["collocated", "environment"]
    assert doc["lights"][1]["map"] == "env.exr" and doc["lights"][1]["scale"] == 1.5
    assert np.allclose(doc["lights"][1]["to_world"], z_up(30.0), atol=0)
    assert all("light" not in fr and "lights" not in fr and "light_position" not in fr for fr in doc["frames"])
    assert sorted(p.name for p in tmp_path.glob("*.exr")) == ["env.exr"]
    got = load_capture(tmp_path)
    assert torch.equal(got.images, obs.images)
    _same_lights(got.views, views)
    _rays_close(got.views, views)
    assert got.views[0].environment.name == "env.exr" and got.meta["environment_maps"] == ["env.exr"]


def test_environment_alone_is_one_top_level_light(tmp_path):
    env = EnvironmentLight(_map(1))                              # identity to_world (Mitsuba's default)
    views = _with(_flash_views(2), env, flash=False)
    save_transforms(Observations(views, _images(2), _mesh()), tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    assert doc["light"] == {"type": "environment", "map": "env.exr", "scale": 1.0,
                            "to_world": [[float(i == j) for j in range(4)] for i in range(4)]}
    _same_lights(load_capture(tmp_path).views, views)


def test_views_with_different_lights_get_per_frame_lights_and_each_map_is_written_once(tmp_path):
    a, b = _map(2), _map(3, h=4, w=8)
    base = _flash_views(4)
    views = [View(base[0].camera, (base[0].lights[0], EnvironmentLight(a, to_world=z_up(0.0))), "v0"),
             View(base[1].camera, (EnvironmentLight(a, 2.0, z_up(90.0)),), "v1"),           # same map, turned
             View(base[2].camera, (PointLight((3.0, 0.0, 5.0), 40.0), base[2].lights[0],
                                   EnvironmentLight(b)), "v2"),
             View(base[3].camera, (PointLight((0.0, 3.0, 5.0), 9.0),), "v3")]             # no environment
    obs = Observations(views, _images(4), _mesh())
    save_transforms(obs, tmp_path, "png")
    doc = json.loads((tmp_path / "transforms.json").read_text())
    fr = doc["frames"]
    assert "light" not in doc and "lights" not in doc
    assert [L["type"] for L in fr[0]["lights"]] == ["collocated", "environment"]
    assert fr[1]["light"]["type"] == "environment" and fr[1]["light"]["scale"] == 2.0
    assert [L["type"] for L in fr[2]["lights"]] == ["point", "collocated", "environment"]
    assert fr[3]["light"] == {"type": "point", "position": [0.0, 3.0, 5.0], "power": [9.0, 9.0, 9.0]}
    maps = sorted(p.name for p in tmp_path.glob("env*.exr"))
    assert len(maps) == 2 and fr[0]["lights"][1]["map"] == fr[1]["light"]["map"] != fr[2]["lights"][2]["map"]
    got = load_capture(tmp_path)
    _same_lights(got.views, views)
    assert got.meta["environment_maps"] == [fr[0]["lights"][1]["map"], fr[2]["lights"][2]["map"]]


def test_flash_only_captures_keep_the_layout_they_had(tmp_path):
    """No environment and one light per view: the top-level collocated light or per-frame light_position, as
    before (readers of the older format read them)."""
    views = _flash_views(2)
    save_transforms(Observations(views, _images(2), _mesh()), tmp_path / "a")
    doc = json.loads((tmp_path / "a" / "transforms.json").read_text())
    assert doc["light"] == {"type": "collocated", "power": [5.0, 5.0, 5.0]} and not list((tmp_path / "a").glob("env*"))
    moved = [View(v.camera, (PointLight((1.0, 2.0, 6.0), 3.0),), v.name) for v in views]
    save_transforms(Observations(moved, _images(2), _mesh()), tmp_path / "b")
    doc = json.loads((tmp_path / "b" / "transforms.json").read_text())
    assert "light" not in doc and doc["frames"][1]["light_position"] == [1.0, 2.0, 6.0]
    _same_lights(load_capture(tmp_path / "b").views, moved)


# ------------------------------------------------------------------ hand-written files
@pytest.fixture
def hand(tmp_path):
    """A 3-frame capture written by hand (no light yet): a sphere mesh, EXR photos, a map ``sky.exr``."""
    d = tmp_path / "hand"
    obs = Observations(_flash_views(3), _images(3), _mesh())
    save_transforms(obs, d)
    write_exr(d / "sky.exr", _map(4))
    doc = json.loads((d / "transforms.json").read_text())
    doc.pop("light")
    return d, doc


def _write(d, doc):
    (d / "transforms.json").write_text(json.dumps(doc))


def test_a_frames_own_lights_win_and_light_position_keeps_the_top_level_environment(hand):
    d, doc = hand
    env = {"type": "environment", "map": "sky.exr", "scale": 0.5}
    doc["lights"] = [{"type": "collocated", "power": 4.0}, env]
    doc["frames"][1]["light"] = {"type": "point", "position": [0, 0, 9], "power": 2.0}    # its own: no environment
    doc["frames"][2]["light_position"] = [1, 0, 9]                                        # replaces the flash only
    _write(d, doc)
    got = load_capture(d)
    v0, v1, v2 = got.views
    sky = EnvironmentLight(_map(4), 0.5)
    assert v0.lights == (PointLight(v0.camera.position, 4.0), sky)
    assert v1.lights == (PointLight((0.0, 0.0, 9.0), 2.0),)
    assert v2.lights == (PointLight((1.0, 0.0, 9.0), 4.0), sky)                # the top-level flash's power
    assert v0.environment is v2.environment                                     # one object per map and setting
    doc.pop("lights")
    doc["light"] = env
    doc["frames"][2]["light_power"] = 7.0
    _write(d, doc)
    got = load_capture(d)
    assert got.views[0].lights == (sky,) and got.views[2].lights == (PointLight((1.0, 0.0, 9.0), 7.0), sky)


def test_each_map_is_read_once(hand, monkeypatch):
    d, doc = hand
    calls = []
    real = EnvironmentLight.from_file.__func__
    monkeypatch.setattr(EnvironmentLight, "from_file",
                        classmethod(lambda cls, p, *a, **k: calls.append(p) or real(cls, p, *a, **k)))
    doc["light"] = {"type": "environment", "map": "sky.exr"}
    doc["frames"][1]["lights"] = [{"type": "collocated", "power": 1.0},
                                  {"type": "environment", "map": "./sky.exr", "scale": 2.0, "to_world": z_up(45)}]
    _write(d, doc)
    got = load_capture(d)
    assert len(calls) == 1
    assert torch.equal(got.views[0].environment.radiance, got.views[1].environment.radiance)
    assert got.views[1].environment.scale == 2.0 and got.views[1].environment.to_world == z_up(45)


@pytest.mark.parametrize("units, up", [("cm", "y"), ("m", "-y"), ("mm", "-z")])
def test_to_world_is_in_the_files_frame_and_turns_with_the_poses(tmp_path, units, up):
    """A z-up cm capture rewritten in another frame (poses, mesh and the environment's to_world rotated by the
    inverse up conversion, lengths divided): the same views, the same environment."""
    env = EnvironmentLight(_map(5), to_world=z_up(20.0))
    views = _with(_flash_views(2), env)
    save_transforms(Observations(views, _images(2), _mesh()), tmp_path)
    want = load_capture(tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    s = {"cm": 1.0, "m": 100.0, "mm": 0.1}[units]
    inv = np.eye(4)
    inv[:3, :3] = UP_AXES[up].T
    for fr in doc["frames"]:
        m = inv @ np.array(fr["transform_matrix"])
        m[:3, 3] /= s
        fr["transform_matrix"] = m.tolist()
    doc["lights"][0]["power"] = [p / s**2 for p in doc["lights"][0]["power"]]
    doc["lights"][1]["to_world"] = (inv @ np.array(doc["lights"][1]["to_world"])).tolist()
    doc.update(units=units, up=up)
    mesh = Mesh(_mesh().vertices @ UP_AXES[up] / s, _mesh().faces, _mesh().uv, _mesh().normals @ UP_AXES[up])
    mesh.to_trimesh().export(str(tmp_path / doc["mesh"]))
    _write(tmp_path, doc)
    got = load_capture(tmp_path)
    _rays_close(got.views, want.views)
    e = got.views[0].environment
    assert np.allclose(e.to_world, env.to_world, atol=1e-12) and e.scale == env.scale
    dirs = torch.randn(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    assert torch.allclose(e.eval(dirs), env.eval(dirs), atol=1e-5)


def test_a_y_up_file_with_mitsubas_default_to_world_has_its_zenith_on_plus_z(hand):
    d, doc = hand
    zen = np.full((8, 16, 3), 0.1, dtype=np.float32)
    zen[0] = 5.0                                                                 # row 0: the map's zenith
    write_exr(d / "zen.exr", zen)
    doc["light"] = {"type": "environment", "map": "zen.exr"}
    doc["up"] = "y"
    _write(d, doc)
    e = load_transforms(d).views[0].environment
    assert e.eval(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0].tolist() == pytest.approx([5.0] * 3)
    assert np.allclose(np.array(e.to_world)[:3, :3], UP_AXES["y"])


def test_a_mirrored_to_world_is_accepted(hand):
    """Mitsuba scenes flip maps with a mirror (``scale x=-1``): orthonormal, so rigid enough for a direction."""
    d, doc = hand
    doc["light"] = {"type": "environment", "map": "sky.exr", "to_world": np.diag([-1.0, 1, 1, 1]).tolist()}
    _write(d, doc)
    assert load_capture(d).views[0].environment.to_world[0][0] == -1.0


# ------------------------------------------------------------------ bad input: one line naming the field
def _bad_maps(d):
    write_png(d / "fake.exr", np.full((4, 8, 3), 0.5, dtype=np.float32))        # a PNG named .exr
    nan, neg = _map(6), _map(7)
    nan[2, 3, 1] = np.nan
    neg[1, 1, 0] = -0.5
    write_exr(d / "nan.exr", nan)
    write_exr(d / "neg.exr", neg)


def _env(**kv):
    return {"type": "environment", "map": "sky.exr", **kv}


_SCALED = (np.diag([1.1, 1.0, 1.0, 1.0])).tolist()
BAD = [
    ("missing map", {"light": _env(map="gone.exr")}, ["light.map 'gone.exr'", "not found"]),
    ("not HDR", {"light": _env(map="fake.exr")}, ["light.map 'fake.exr'", "not an HDR image"]),
    ("NaN", {"lights": [{"type": "collocated", "power": 1}, _env(map="nan.exr")]},
     ["lights[1].map 'nan.exr'", "NaN"]),
    ("negative", {"light": _env(map="neg.exr")}, ["light.map 'neg.exr'", "negative"]),
    ("non-rigid", {"light": _env(to_world=_SCALED)}, ["light.to_world is not rigid", "column norms"]),
    ("not 4x4", {"light": _env(to_world=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])}, ["light.to_world", "4x4"]),
    ("unknown type", {"lights": [_env(), {"type": "spot", "power": 1}]},
     ["lights[1].type 'spot'", "collocated, point, environment"]),
    ("two environments", {"lights": [_env(), _env(scale=2)]}, ["more than one environment"]),
    ("light and lights", {"light": _env(), "lights": [_env()]}, ["light and lights are both given"]),
    ("negative scale", {"light": _env(scale=-1)}, ["light.scale", ">= 0"]),
    ("no map", {"light": {"type": "environment"}}, ["light.map must be the path"]),
    ("empty list", {"lights": []}, ["lights must be a non-empty list"]),
]


@pytest.mark.parametrize("case, top, words", BAD, ids=[b[0] for b in BAD])
def test_bad_environment_lights_are_one_line_errors(hand, case, top, words):
    d, doc = hand
    _bad_maps(d)
    doc.update(top)
    _write(d, doc)
    msg = raises_one_line(lambda: load_capture(d), *words)
    assert "transforms.json" in msg


@pytest.mark.parametrize("frame, words", [
    ({"light": {"type": "area", "power": 1}}, ["frames[1].light.type 'area'", "environment"]),
    ({"lights": [_env(), _env(scale=3)]}, ["frames[1].lights", "more than one"]),
    ({"lights": [_env(map="gone.exr")]}, ["frames[1].lights[0].map 'gone.exr'", "not found"]),
    ({"light": _env(), "light_position": [0, 0, 9]}, ["frames[1]", "light_position"]),
])
def test_bad_frame_lights_name_the_frame(hand, frame, words):
    d, doc = hand
    _bad_maps(d)
    doc["light"] = {"type": "collocated", "power": 1.0}
    doc["frames"][1].update(frame)
    _write(d, doc)
    raises_one_line(lambda: load_capture(d), *words)


def test_the_command_line_says_each_bad_input_in_one_line_and_exits_2(hand, capsys):
    d, doc = hand
    _bad_maps(d)
    for case, top, words in BAD[:7]:                 # missing, not HDR, NaN, negative, non-rigid, 4x4, unknown type
        bad = dict(doc, **top)
        bad.pop("light", None) if "lights" in top else None
        _write(d, bad)
        assert main(["inspect", str(d)]) == 2, case
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("bayes-brdf: error:") and words[0] in err, (case, err)
    _write(d, dict(doc, light=_env(map="fake.exr")))
    p = subprocess.run([sys.executable, "-m", "bayes_brdf", "inspect", str(d)], capture_output=True, text=True,
                       timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "not an HDR image" in lines[0] and "Traceback" not in p.stderr


# ------------------------------------------------------------------ the observation bundle
def _bundle_obs():
    a = _map(8)
    cam = [RectifiedCamera((0.0, 0.0, 9.0), resolution=4), RectifiedCamera((1.0, 0.0, 9.0), resolution=4)]
    views = [View(cam[0], (PointLight((0.0, 0.0, 9.0), 5.0), EnvironmentLight(a, 2.0, z_up(10.0), "room")), "a"),
             View(cam[1], (EnvironmentLight(a, 1.0, z_up(50.0)),), "b"),         # the same map, turned
             View(cam[0], (PointLight((0.0, 0.0, 9.0), 5.0),), "c")]
    return Observations(views, torch.rand(3, 4, 4, 3, generator=torch.Generator().manual_seed(1)),
                        PlanarSample(2.0), meta={"units": "cm"})


def test_a_bundle_stores_the_environment_maps(tmp_path):
    obs = _bundle_obs()
    save_observations(obs, tmp_path / "b")
    doc = json.loads((tmp_path / "b" / "observations.json").read_text())
    assert doc["format_version"] == 3 and len(doc["environments"]) == 2
    assert len(set(doc["environments"].values())) == 1 and len(list((tmp_path / "b").glob("environment_*.exr"))) == 1
    back = load_observations(tmp_path / "b")
    assert back.views == obs.views and torch.equal(back.images, obs.images)
    assert torch.equal(back.views[0].environment.radiance, obs.views[0].environment.radiance)
    again = load_capture(tmp_path / "b", resolution=2)                 # through the capture loader, resampled
    assert [v.lights for v in again.views] == [v.lights for v in obs.views]
    save_observations(obs.subset([2]), tmp_path / "flash")            # no environment: still version 1
    assert json.loads((tmp_path / "flash" / "observations.json").read_text())["format_version"] == 1
    assert "environments" not in json.loads((tmp_path / "flash" / "observations.json").read_text())


def test_a_bundle_whose_map_is_missing_or_damaged_is_one_line(tmp_path):
    save_observations(_bundle_obs(), tmp_path / "b")
    (m,) = (tmp_path / "b").glob("environment_*.exr")
    shutil.copy(m, tmp_path / "keep.exr")
    m.unlink()
    raises_one_line(lambda: load_observations(tmp_path / "b"), "environment map", "missing")
    bad = _map(8)
    bad[0, 0, 0] = -1.0
    write_exr(m, bad)
    raises_one_line(lambda: load_observations(tmp_path / "b"), "negative")
    write_exr(m, _map(9))                                  # another map: the views' digests no longer match
    raises_one_line(lambda: load_observations(tmp_path / "b"), "does not match")
