"""transforms.json captures (NeRF / nerfstudio poses + a mesh): what a user relies on when loading or writing one.

Cameras follow the OpenGL convention (look along -z, +y up, +x right), everything is converted to cm and
z-up (light power times the squared length scale, so radiance is unchanged), the writer round-trips, and
every malformed file gives one line naming the frame or key.
"""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.io import describe, load_capture, load_transforms, save_transforms, write_exr
from bayes_brdf.io.images import linear_to_srgb, resample, srgb_to_linear
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import PerspectiveCamera
from bayes_brdf.render.lights import PointLight
from bayes_brdf.render.maps import SVBRDF
from bayes_brdf.render.mesh import UP_AXES, Mesh
from bayes_brdf.render.views import View, collocated_views, light_stage_views

from .helpers import raises_one_line

H, W = 12, 16            # non-square on purpose


def _mesh():
    return Mesh.sphere(1.0, center=(0.0, 0.0, 0.5), rings=8, segments=16)


def _images(n, h=H, w=W, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, h, w, 3, generator=g) * 0.9


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A 3-view collocated capture (EXR) of a small sphere, and the observations it was written from."""
    m = _mesh()
    views = collocated_views(3, radius=4.0, target=m.center, resolution=(H, W), fov=40.0, power=7.0)
    obs = Observations(views, _images(3), m)
    d = tmp_path_factory.mktemp("cap")
    save_transforms(obs, d)
    return d, obs


@pytest.fixture
def cap(base, tmp_path):
    """A fresh copy of the base capture to edit, and its transforms.json as a dict."""
    d = tmp_path / "cap"
    shutil.copytree(base[0], d)
    return d, json.loads((d / "transforms.json").read_text())


def _write(d, doc):
    (d / "transforms.json").write_text(json.dumps(doc))


def _rays(cam):
    return cam.rays(dtype=torch.float64)


def _same_views(a, b, tol=1e-9):
    assert len(a) == len(b)
    for va, vb in zip(a, b):
        assert va.camera.resolution == vb.camera.resolution
        assert va.camera.fov == pytest.approx(vb.camera.fov, rel=1e-12)
        (oa, da), (ob, db) = _rays(va.camera), _rays(vb.camera)
        assert torch.allclose(oa, ob, rtol=0, atol=tol) and torch.allclose(da, db, rtol=0, atol=tol)
        assert len(va.lights) == len(vb.lights) == 1
        la, lb = va.lights[0], vb.lights[0]
        assert np.allclose(la.position, lb.position, rtol=0, atol=tol) and np.allclose(la.power, lb.power, rtol=1e-12)


def _same_mesh(a, b, tol=1e-12):
    assert np.array_equal(a.faces, b.faces)
    for k in ("vertices", "uv", "normals"):
        assert np.allclose(getattr(a, k), getattr(b, k), rtol=0, atol=tol), k


def _rewrite_obj(src, dst, fn):
    """Copy an OBJ, mapping every ``v`` position by ``fn(p, "v")`` and ``vn`` normal by ``fn(n, "vn")``."""
    out = []
    for line in src.read_text().splitlines():
        parts = line.split()
        if parts and parts[0] in ("v", "vn"):
            x = fn(np.array([float(t) for t in parts[1:4]]), parts[0])
            line = f"{parts[0]} " + " ".join(repr(float(c)) for c in x)
        out.append(line)
    dst.write_text("\n".join(out) + "\n")


# ------------------------------------------------------------------ round trips
def test_exr_round_trip_gives_the_same_observations(base):
    d, obs = base
    for path in (d, d / "transforms.json"):
        got = load_capture(path)
        assert torch.equal(got.images, obs.images)          # EXR: exact
        _same_views(got.views, obs.views)
        _same_mesh(got.surface, obs.surface)
        assert bool(got.mask.all()) and not bool(got.saturated.any())
        assert got.meta["format"] == "transforms" and got.meta["units"] == "cm"
        assert got.meta["mesh"].endswith("sphere.obj") and got.meta["native_resolution"] == [H, W]
    doc = json.loads((d / "transforms.json").read_text())
    assert doc["light"] == {"type": "collocated", "power": [7.0, 7.0, 7.0]} and doc["w"] == W and doc["h"] == H
    text = describe(load_capture(d, fmt="transforms"))
    assert "capture: transforms" in text and "mesh: 'sphere'" in text and "frame_002" in text


def test_png_round_trip_within_8_bit_quantisation_and_flags_clipped_pixels(tmp_path):
    m = _mesh()
    views = collocated_views(2, radius=4.0, target=m.center, resolution=(H, W), power=3.0)
    imgs = _images(2)
    imgs[0, 0, :4] = 1.5                                    # clips in an 8-bit PNG
    save_transforms(Observations(views, imgs, m), tmp_path, "png")
    got = load_capture(tmp_path)
    codes = torch.round(linear_to_srgb(imgs.double(), 2.2).clamp(0, 1) * 255)
    assert torch.allclose(got.images.double(), srgb_to_linear(codes / 255, 2.2), atol=1e-6)
    assert torch.equal(got.saturated, codes.amax(-1) == 255) and int(got.saturated.sum()) >= 4
    assert float((got.images - imgs.clamp(max=1)).abs().max()) < 0.01
    _same_views(got.views, views)


def test_masks_saturation_and_per_frame_lights_round_trip(tmp_path):
    m = _mesh()
    views = light_stage_views([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], [[0.0, 0.8, 0.6]], 4.0, 6.0,
                              resolution=(H, W), power=9.0, target=m.center)
    mask = torch.ones(2, H, W, dtype=torch.bool)
    mask[1, 3:5] = False
    sat = torch.zeros(2, H, W, dtype=torch.bool)
    sat[0, 0, 0] = True
    obs = Observations(views, _images(2), m, mask=mask, saturated=sat)
    save_transforms(obs, tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    assert "light" not in doc and doc["frames"][0]["light_position"] == list(views[0].lights[0].position)
    got = load_capture(tmp_path)
    assert torch.equal(got.mask, mask) and torch.equal(got.saturated, sat)
    _same_views(got.views, views)


# ------------------------------------------------------------------ the OpenGL camera convention
def _hand_capture(d, matrix, w=9, h=7, **top):
    """A one-frame capture written by hand: a plane mesh, one EXR, the given camera-to-world matrix."""
    d.mkdir(parents=True, exist_ok=True)
    Mesh.plane(2.0).to_trimesh().export(str(d / "plane.obj"))
    write_exr(d / "img.exr", torch.full((h, w, 3), 0.25))
    doc = {"mesh": "plane.obj", "units": "cm", "camera_angle_x": math.radians(60),
           "light": {"type": "collocated", "power": 2.0},
           "frames": [{"file_path": "img", "transform_matrix": np.asarray(matrix).tolist()}], **top}
    (d / "transforms.json").write_text(json.dumps(doc))
    return d


def test_identity_rotation_at_z5_is_a_camera_looking_down_at_the_origin(tmp_path):
    m = np.eye(4)
    m[2, 3] = 5.0
    obs = load_capture(_hand_capture(tmp_path, m))      # file_path without extension (nerfstudio style)
    cam = obs.views[0].camera
    assert isinstance(cam, PerspectiveCamera) and cam.position == (0.0, 0.0, 5.0) and cam.fov == pytest.approx(60)
    assert cam.resolution == (7, 9) and obs.views[0].lights[0] == PointLight((0.0, 0.0, 5.0), 2.0)
    _, dirs = _rays(cam)
    assert torch.allclose(dirs[:, 3, 4], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64), atol=1e-12)
    right, top = dirs[:, 3, 8], dirs[:, 0, 4]                     # the right-most and top pixel centres
    assert right[0] > 0 and abs(right[1]) < 1e-12 and top[1] > 0 and abs(top[0]) < 1e-12
    half = (8.5 / 9 * 2 - 1) * math.tan(math.radians(30))          # pixel centre of a 60-degree horizontal fov
    assert float(right[0] / -right[2]) == pytest.approx(half, rel=1e-12)
    assert float(top[1] / -top[2]) == pytest.approx((1 - 0.5 / 7 * 2) * math.tan(math.radians(30)) * 7 / 9, rel=1e-12)


def test_rays_follow_the_matrix_columns(tmp_path):
    q, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))                                    # a proper rotation
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = q, (1.0, -2.0, 3.0)
    cam = load_capture(_hand_capture(tmp_path, m)).views[0].camera
    _, dirs = _rays(cam)
    x, y, z = (torch.tensor(q[:, k]) for k in range(3))
    assert torch.allclose(dirs[:, 3, 4], -z, atol=1e-12)
    step_right, step_up = dirs[:, 3, 5] - dirs[:, 3, 4], dirs[:, 2, 4] - dirs[:, 3, 4]
    assert float(step_right @ x) > 0 and abs(float(step_right @ y)) < 1e-12
    assert float(step_up @ y) > 0 and abs(float(step_up @ x)) < 1e-12


def test_focal_length_form_equals_camera_angle_form(cap):
    d, doc = cap
    base = load_capture(d)
    fl = W / (2 * math.tan(doc["camera_angle_x"] / 2))
    for k in ("camera_angle_x", "fl_x", "fl_y"):
        doc.pop(k)
    doc.update(fl_x=fl, fl_y=fl * (1 + 5e-4), cx=W / 2 - 0.5, cy=H / 2 + 0.25)     # within 0.1% / half a pixel
    _write(d, doc)
    got = load_capture(d)
    for a, b in zip(got.views, base.views):
        assert a.camera.fov == pytest.approx(b.camera.fov, rel=1e-12)
    doc.pop("fl_x")                                                 # fl_y alone is the focal length too
    doc["fl_y"] = fl
    _write(d, doc)
    assert load_capture(d).views[0].camera.fov == pytest.approx(base.views[0].camera.fov, rel=1e-12)


# ------------------------------------------------------------------ units and up axis
def _to_file_frame(d, doc, s, rot):
    """Rewrite the cm / z-up capture in ``d`` into a file frame: lengths / s, powers / s^2, rotated by rot^T."""
    inv = rot.T
    for fr in doc["frames"]:
        m = np.array(fr["transform_matrix"])
        m[:3, :3] = inv @ m[:3, :3]
        m[:3, 3] = inv @ m[:3, 3] / s
        fr["transform_matrix"] = m.tolist()
        if "light_position" in fr:
            fr["light_position"] = (inv @ np.array(fr["light_position"]) / s).tolist()
            fr["light_power"] = [p / s**2 for p in fr["light_power"]]
    if "light" in doc:
        doc["light"]["power"] = [p / s**2 for p in doc["light"]["power"]]
    _rewrite_obj(d / doc["mesh"], d / doc["mesh"], lambda p, k: inv @ p / (s if k == "v" else 1.0))
    _write(d, doc)


@pytest.mark.parametrize("units, up", [("m", "z"), ("mm", "z"), ("cm", "y"), ("in", "y")])
def test_units_and_up_axis_convert_to_cm_z_up(cap, units, up):
    d, doc = cap
    want = load_capture(d)
    s = {"m": 100.0, "mm": 0.1, "cm": 1.0, "in": 2.54}[units]
    doc.update(units=units, up=up)
    _to_file_frame(d, doc, s, UP_AXES[up])
    raw = json.loads((d / "transforms.json").read_text())
    got = load_capture(d)
    _same_views(got.views, want.views, tol=1e-9 * max(s, 1))
    t0 = np.array(raw["frames"][0]["transform_matrix"])[:3, 3]
    assert np.allclose(got.views[0].camera.position, s * UP_AXES[up] @ t0, atol=1e-9 * max(s, 1))
    assert np.allclose(got.views[0].lights[0].power, np.array(raw["light"]["power"]) * s**2, rtol=1e-12)
    _same_mesh(got.surface, want.surface, tol=1e-9 * max(s, 1))
    assert got.meta["file_units"] == units and got.meta["up"] == up and got.meta["units"] == "cm"


@pytest.mark.needs_llvm
def test_a_capture_in_metres_renders_the_same_radiance(tmp_path):
    """Positions x 100 and power x 1e4: the rendered pixels of the metre file equal those of the cm file."""
    from bayes_brdf.render.shade import render

    m = _mesh()
    views = light_stage_views([[0.0, 0.0, 1.0], [0.5, 0.5, 0.7071]], [[0.0, 0.8, 0.6]], 4.0, 5.0,
                              resolution=(H, W), power=30.0, target=m.center)
    maps = SVBRDF.constant(albedo=0.5, roughness=0.3).to(torch.float32)
    imgs = render(maps, views, m)[0]
    save_transforms(Observations(views, imgs, m), tmp_path)
    doc = json.loads((tmp_path / "transforms.json").read_text())
    doc["units"] = "m"
    _to_file_frame(tmp_path, doc, 100.0, UP_AXES["z"])
    raw = json.loads((tmp_path / "transforms.json").read_text())
    got = load_capture(tmp_path)
    assert got.views[0].lights[0].power == pytest.approx(tuple(1e4 * p for p in raw["frames"][0]["light_power"]))
    assert np.allclose(got.views[1].lights[0].position, 100 * np.array(raw["frames"][1]["light_position"]))
    again = render(maps, got.views, got.surface)[0]
    assert float(imgs.max()) > 0.05 and torch.allclose(again, imgs, rtol=1e-4, atol=1e-6)


# ------------------------------------------------------------------ resolution
def test_resolution_is_the_longer_side_and_keeps_the_fov(base):
    d, obs = base
    got = load_capture(d, resolution=8)
    assert got.resolution == (6, 8) and got.views[0].camera.resolution == (6, 8)
    assert got.views[0].camera.fov == pytest.approx(obs.views[0].camera.fov)
    assert torch.allclose(got.images, resample(obs.images, (6, 8)))
    assert got.meta["native_resolution"] == [H, W]
    assert load_capture(d, max_resolution=4).resolution == (3, 4)
    assert load_capture(d, max_resolution=64).resolution == (H, W)
    raises_one_line(lambda: load_capture(d, resolution=32), "32", "native")
    raises_one_line(lambda: load_transforms(d, resolution=(8, 8)), "aspect")


# ------------------------------------------------------------------ bad input: one line naming the frame / key
def _drop(*keys):
    def edit(doc):
        for k in keys:
            doc.pop(k, None)
    return edit


def _frame(i, **kv):
    def edit(doc):
        doc["frames"][i].update(kv)
    return edit


def _scaled_matrix(doc):
    m = np.array(doc["frames"][2]["transform_matrix"])
    m[:3, :3] *= 1.01
    doc["frames"][2]["transform_matrix"] = m.tolist()


def _mirrored_matrix(doc):
    m = np.array(doc["frames"][1]["transform_matrix"])
    m[:3, 0] *= -1
    doc["frames"][1]["transform_matrix"] = m.tolist()


def _nan(doc):
    doc["frames"][1]["transform_matrix"][0][3] = float("nan")


@pytest.mark.parametrize("edit, words", [
    (_drop("units"), ["'units'"]),
    (lambda doc: doc.update(units="furlong"), ["furlong", "units"]),
    (lambda doc: doc.update(up="x"), ["up axis", "'x'"]),
    (_drop("mesh"), ["'mesh'"]),
    (lambda doc: doc.update(mesh="gone.obj"), ["gone.obj", "missing"]),
    (_drop("light"), ["no light", "frames[0]"]),
    (lambda doc: doc.update(light={"type": "spot", "power": 1}), ["spot"]),
    (_drop("frames"), ["'frames'"]),
    (_frame(1, file_path="images/nope.exr"), ["frames[1]", "nope.exr", "missing"]),
    (lambda doc: doc["frames"][2].pop("transform_matrix"), ["frames[2]", "transform_matrix"]),
    (lambda doc: doc["frames"][0]["transform_matrix"].pop(), ["frames[0].transform_matrix", "4x4"]),
    (_scaled_matrix, ["frames[2].transform_matrix is not rigid"]),
    (_mirrored_matrix, ["frames[1].transform_matrix is not rigid", "det"]),
    (_nan, ["frames[1].transform_matrix", "not finite"]),
    (lambda doc: doc.update(w=W + 1), ["frames[0]", f"{W}x{H}", f"w = {W + 1}"]),
    (_frame(1, h=H * 2), ["frames[1]", f"frames[1].h = {2 * H}"]),
    (lambda doc: doc.update(cx=W / 2 + 3), ["cx", "off-centre principal points are not supported"]),
    (lambda doc: doc.update(fl_y=doc["fl_x"] * 1.01), ["fl_y", "non-square pixels"]),
    (lambda doc: doc.update(camera_angle_x=doc["camera_angle_x"] * 1.1), ["camera_angle_x", "disagrees"]),
    (_frame(2, k1=0.05), ["frames[2].k1", "distortion"]),
    (lambda doc: doc.update(camera_model="OPENCV_FISHEYE"), ["OPENCV_FISHEYE"]),
    (_drop("camera_angle_x", "fl_x", "fl_y"), ["frames[0]", "field of view"]),
    (lambda doc: (doc.pop("light"), doc["frames"][0].update(light_position=[0, 0, 9])), ["frames[0]", "light power"]),
    (_frame(0, light_power=[1, float("inf"), 1]), ["frames[0].light_power", "not finite"]),
    (_frame(0, mask="masks/none.png"), ["frames[0]", "mask", "none.png"]),
])
def test_bad_transforms_are_one_line_errors(cap, edit, words):
    d, doc = cap
    edit(doc)
    _write(d, doc)
    raises_one_line(lambda: load_capture(d), *words)


def test_bad_files_are_one_line_errors(cap):
    d, doc = cap
    (d / "transforms.json").write_text('{"units": "cm", "frames": [')
    raises_one_line(lambda: load_capture(d), "transforms.json", "malformed JSON")
    _write(d, doc)
    write_exr(d / "images" / "frame_001.exr", torch.zeros(H, W + 2, 3))
    raises_one_line(lambda: load_capture(d), "frames[1]", f"{W + 2}x{H}")


def test_save_transforms_refuses_what_the_format_cannot_hold(tmp_path):
    from bayes_brdf.render.cameras import RectifiedCamera
    from bayes_brdf.render.surface import PlanarSample

    m = _mesh()
    persp = PerspectiveCamera((0, 0, 4.0), resolution=(2, 2))
    raises_one_line(lambda: save_transforms((
        [View.collocated(persp)], torch.zeros(1, 2, 2, 3), PlanarSample(2.0)), tmp_path), "mesh")
    raises_one_line(lambda: save_transforms((
        [View.collocated(RectifiedCamera((0, 0, 4.0), resolution=2))], torch.zeros(1, 2, 2, 3), m), tmp_path),
        "RectifiedCamera")
    flat = View(persp, (PointLight((0, 0, 4.0)), PointLight((1, 0, 4.0), falloff=False)))
    raises_one_line(lambda: save_transforms(([flat], torch.zeros(1, 2, 2, 3), m), tmp_path), "without distance falloff")


# ------------------------------------------------------------------ the command line
def test_cli_inspect_reads_a_transforms_capture(base, capsys):
    d, _ = base
    assert main(["inspect", str(d)]) == 0
    out = capsys.readouterr().out
    assert "capture: transforms" in out and "mesh: 'sphere'" in out and f"{H}x{W}" in out
    assert main(["inspect", str(d / "transforms.json"), "--format", "transforms", "--resolution", "8"]) == 0
    assert "6x8" in capsys.readouterr().out


def test_cli_bad_transforms_is_one_line_exit_2(cap):
    d, doc = cap
    doc.pop("units")
    _write(d, doc)
    p = subprocess.run([sys.executable, "-m", "bayes_brdf", "inspect", str(d)], capture_output=True, text=True,
                       timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "'units'" in lines[0] and "Traceback" not in p.stderr


@pytest.mark.needs_llvm
def test_cli_render_on_a_mesh_writes_a_capture_inspect_reads(tmp_path, capsys):
    m = _mesh()
    mm = Mesh(m.vertices * 10, m.faces, m.uv, m.normals, name="ball")       # the same ball, in mm
    mm.to_trimesh().export(str(tmp_path / "ball.obj"))
    out = tmp_path / "out"
    assert main(["render", "marble", "--mesh", str(tmp_path / "ball.obj"), "--mesh-units", "mm",
                 "--views", "sobol:2", "--resolution", "12", "--out", str(out)]) == 0
    assert "transforms.json" in capsys.readouterr().out
    assert (out / "transforms.json").is_file() and (out / "ball.obj").is_file() and (out / "maps").is_dir()
    got = load_capture(out)
    assert len(got) == 2 and got.resolution == (12, 12) and got.meta["format"] == "transforms"
    assert got.surface.radius == pytest.approx(m.radius, rel=1e-6)         # mm -> cm
    centre = np.array(got.surface.center)
    for v in got.views:                                                     # around the centre, 3 radii away
        assert np.linalg.norm(np.array(v.camera.position) - centre) == pytest.approx(3 * m.radius, rel=1e-6)
        assert v.lights[0].position == v.camera.position
    assert float(got.images.max()) > 0.05
    assert main(["inspect", str(out)]) == 0 and "mesh: 'ball'" in capsys.readouterr().out
    assert main(["render", "marble", "--mesh", "sphere", "--camera", "rectified", "--out", str(tmp_path / "x")]) == 2
    assert main(["render", "marble", "--layout", "transforms", "--out", str(tmp_path / "y")]) == 2
