"""Triangle meshes: file loading (units, up axis, uv, normals), xatlas atlases, built-in shapes, state round trip."""
import math

import numpy as np
import pytest
import torch
import trimesh
from trimesh.visual import TextureVisuals

from bayes_brdf.errors import InputError
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.surface import PlanarSample


# ---------------------------------------------------------------- helpers
def _ray_hits(origins, dirs, vertices, faces, eps=1e-9):
    """Möller-Trumbore: distance to the nearest triangle hit with t > eps per ray (inf when none)."""
    tri = vertices[faces]                       # [F, 3, 3]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(dirs[:, None], e2[None])       # [R, F, 3]
    det = np.einsum("rfk,fk->rf", p, e1)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origins[:, None] - tri[None, :, 0]
    u = np.einsum("rfk,rfk->rf", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rk,rfk->rf", dirs, q) * inv
    t = np.einsum("fk,rfk->rf", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps)
    return np.where(hit, t, np.inf).min(axis=1)


def _uv_areas(mesh):
    t = mesh.uv[mesh.faces]
    return 0.5 * ((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                  - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1]))


def _quad_file_mesh():
    """A small non-planar quad strip with uv, in a y-up frame (as glTF would have it)."""
    v = np.array([[0, 0, 0], [10, 0, 0], [10, 5, 0], [0, 5, 2], [5, 8, -1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    uv = np.array([[0.1, 0.2], [0.9, 0.2], [0.9, 0.8], [0.1, 0.7], [0.5, 0.95]])
    return v, f, uv


def _one_line_error(excinfo, *parts):
    msg = str(excinfo.value)
    assert "\n" not in msg
    for p in parts:
        assert str(p) in msg, (p, msg)


# ---------------------------------------------------------------- files
@pytest.mark.parametrize("ext", ["obj", "ply", "glb"])
def test_load_keeps_file_uv_and_positions(tmp_path, ext):
    v, f, uv = _quad_file_mesh()
    path = tmp_path / f"quad.{ext}"
    trimesh.Trimesh(v, f, visual=TextureVisuals(uv=uv), process=False).export(path)
    m = Mesh.load(path)
    assert m.meta["uv_source"] == "file" and m.meta["scale"] == 1.0 and m.name == "quad"
    assert m.num_faces == 3
    tol = 1e-6 if ext == "glb" else 1e-12   # glTF stores float32
    # compare per face corner: vertex order may differ from ours, corners may not
    np.testing.assert_allclose(m.vertices[m.faces], v[f], atol=tol * 10)
    np.testing.assert_allclose(m.uv[m.faces], uv[f], atol=tol)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64 and not m.uv.flags.writeable


def test_load_units_and_up_axis(tmp_path):
    v, f, uv = _quad_file_mesh()
    path = tmp_path / "yup.glb"
    trimesh.Trimesh(v, f, visual=TextureVisuals(uv=uv), process=False).export(path)
    m = Mesh.load(path, units="mm", up="y")               # scene units cm
    expected = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1) * 0.1
    np.testing.assert_allclose(m.vertices[m.faces], expected[f], atol=1e-6)
    np.testing.assert_allclose(m.uv[m.faces], uv[f], atol=1e-6)
    assert m.meta["file_units"] == "mm" and m.meta["up"] == "y" and m.meta["scale"] == pytest.approx(0.1)
    # a proper rotation: the winding (face normals vs. shading normals) survives
    assert np.all(np.einsum("fk,fk->f", m.face_normals, m.normals[m.faces].mean(1)) > 0)
    m_in = Mesh.load(path, units="in", scene_units="m")
    np.testing.assert_allclose(m_in.vertices[m_in.faces], v[f] * 0.0254, atol=1e-7)


def test_normals_from_file_or_area_weighted(tmp_path):
    v, f, uv = _quad_file_mesh()
    tilted = np.tile(np.array([0.0, 0.6, 0.8]), (len(v), 1))  # not the geometric normals
    path = tmp_path / "n.ply"
    trimesh.Trimesh(v, f, vertex_normals=tilted, visual=TextureVisuals(uv=uv), process=False).export(path)
    m = Mesh.load(path, up="y")
    assert m.meta["normals_source"] == "file"
    np.testing.assert_allclose(m.normals, np.tile([0.0, -0.8, 0.6], (m.num_vertices, 1)), atol=1e-6)

    path = tmp_path / "plain.obj"
    trimesh.Trimesh(v, f, visual=TextureVisuals(uv=uv), process=False).export(path)
    m = Mesh.load(path)
    assert m.meta["normals_source"] == "faces"
    # area-weighted: sum of cross products of the faces around each vertex
    tri = m.vertices[m.faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    want = np.zeros_like(m.vertices)
    for k in range(3):
        np.add.at(want, m.faces[:, k], fn)
    np.testing.assert_allclose(m.normals, want / np.linalg.norm(want, axis=1, keepdims=True), atol=1e-12)


def test_file_without_uv_gets_atlas_and_uv_modes(tmp_path):
    v, f, uv = _quad_file_mesh()
    path = tmp_path / "nouv.ply"
    trimesh.Trimesh(v, f, process=False).export(path)
    m = Mesh.load(path, atlas_resolution=64, atlas_padding=1)
    assert m.meta["uv_source"] == "xatlas" and m.meta["atlas"]["resolution"] == 64
    np.testing.assert_allclose(m.vertices[m.faces], v[f])
    with pytest.raises(InputError) as e:
        Mesh.load(path, uv="file")
    _one_line_error(e, path, "no usable uv")
    withuv = tmp_path / "uv.obj"
    trimesh.Trimesh(v, f, visual=TextureVisuals(uv=uv), process=False).export(withuv)
    assert Mesh.load(withuv, uv="atlas").meta["uv_source"] == "xatlas"


@pytest.mark.shared
def test_bunny_gets_a_deterministic_non_overlapping_atlas(shared_data):
    path = shared_data / "psdr_assets" / "bunny_low.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    a, b = Mesh.load(path), Mesh.load(path)
    assert a == b and a.digest == b.digest and hash(a) == hash(b)
    assert a.num_faces == 4968 and a.meta["uv_source"] == "xatlas"
    raw = trimesh.load(path, process=False, force="mesh")
    np.testing.assert_array_equal(a.vertices[a.faces], raw.vertices[raw.faces])   # faces kept, in order
    assert a.uv.min() >= 0 and a.uv.max() <= 1
    atlas = a.meta["atlas"]
    assert atlas["resolution"] == 256 and max(atlas["width"], atlas["height"]) <= 256
    area = np.abs(_uv_areas(a))
    assert np.all(area > 0) and area.sum() < 1
    # rasterise the atlas: no texel centre lies strictly inside two triangles
    res = 256
    cover = np.zeros((res, res), dtype=np.int32)
    tri = a.uv[a.faces] * res                          # texel units, v up (row index irrelevant here)
    lo = np.floor(tri.min(1) - 0.5).astype(int).clip(0, res - 1)
    hi = np.ceil(tri.max(1) - 0.5).astype(int).clip(0, res - 1)
    for t, (x0, y0), (x1, y1) in zip(tri, lo, hi):
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
        d = (t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[2, 0] - t[0, 0]) * (t[1, 1] - t[0, 1])
        w1 = ((xs - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[2, 0] - t[0, 0]) * (ys - t[0, 1])) / d
        w2 = ((t[1, 0] - t[0, 0]) * (ys - t[0, 1]) - (xs - t[0, 0]) * (t[1, 1] - t[0, 1])) / d
        inside = (w1 > 1e-6) & (w2 > 1e-6) & (1 - w1 - w2 > 1e-6)
        cover[y0:y1 + 1, x0:x1 + 1] += inside
    assert cover.max() == 1 and cover.sum() > 0.4 * res * res


def test_bad_files_raise_one_line_input_errors(tmp_path):
    missing = tmp_path / "missing.obj"
    with pytest.raises(InputError) as e:
        Mesh.load(missing)
    _one_line_error(e, missing, "not found")
    good = tmp_path / "tri.obj"
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False).export(good)
    with pytest.raises(InputError) as e:
        Mesh.load(good, units="furlong")
    _one_line_error(e, good, "furlong", "mm")
    with pytest.raises(InputError) as e:
        Mesh.load(good, up="x")
    _one_line_error(e, good, "up axis")
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(20, 3))).export(cloud)
    with pytest.raises(InputError) as e:
        Mesh.load(cloud)
    _one_line_error(e, cloud, "no faces")
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not\nan obj file\n")
    with pytest.raises(InputError) as e:
        Mesh.load(junk)
    _one_line_error(e, junk, "no faces")
    txt = tmp_path / "mesh.txt"
    txt.write_text("hello")
    with pytest.raises(InputError) as e:
        Mesh.load(txt)
    _one_line_error(e, txt, "unsupported")


def test_constructor_validates():
    v, f, uv, n = [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], [[0, 0], [1, 0], [0, 1]], [[0, 0, 2.0]] * 3
    m = Mesh(v, f, uv, n)
    np.testing.assert_array_equal(m.normals, [[0, 0, 1.0]] * 3)   # renormalised
    for kwargs, text in [(dict(faces=[[0, 1, 3]]), "face indices"), (dict(uv=None), "uv missing"),
                         (dict(vertices=[[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), "non-finite"),
                         (dict(uv=[[0, 0], [2, 0], [0, 1]]), "outside [0, 1]"), (dict(normals=[[0, 0, 0]] * 3), "zero"),
                         (dict(faces=[[0, 1]]), "shape")]:
        with pytest.raises(InputError) as e:
            Mesh(**{**dict(vertices=v, faces=f, uv=uv, normals=n), **kwargs})
        _one_line_error(e, text)


# ---------------------------------------------------------------- shapes
def test_plane_matches_planar_sample_convention():
    size = 3.7
    m = Mesh.plane(size)
    assert m.num_faces == 2 and PlanarSample(size).align_corners is False
    assert np.all(m.face_normals == [0, 0, 1]) and np.all(m.normals == [0, 0, 1])
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.uniform(-size / 2, size / 2, (200, 2)), np.zeros((200, 1))], axis=1)
    # barycentric interpolation of uv in the triangle containing each point
    got = np.full((200, 2), np.nan)
    for face in m.faces:
        a, b, c = m.vertices[face][:, :2]
        T = np.stack([b - a, c - a], axis=1)
        w = np.linalg.solve(T, (pts[:, :2] - a).T).T
        inside = (w >= -1e-12).all(1) & (w.sum(1) <= 1 + 1e-12)
        uv = m.uv[face]
        got[inside] = ((1 - w.sum(1))[:, None] * uv[0] + w[:, :1] * uv[1] + w[:, 1:] * uv[2])[inside]
    assert not np.isnan(got).any()
    coords = Mesh.grid_coords(torch.from_numpy(got))
    want = PlanarSample(size).texture_coords(torch.from_numpy(pts.T))
    torch.testing.assert_close(coords, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Mesh.grid_coords(got), want.numpy(), atol=1e-12)
    with pytest.raises(InputError) as e:
        Mesh.plane(size, grid="endpoints")
    _one_line_error(e, "endpoints")


def test_sphere_positions_normals_and_latlong_uv():
    c, r = np.array([0.5, -1.0, 2.0]), 1.5
    m = Mesh.sphere(r, center=c, rings=12, segments=24)
    d = m.vertices - c
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), r, atol=1e-12)
    np.testing.assert_allclose(m.normals, d / r, atol=1e-12)
    assert m.num_faces == 2 * 24 * 11
    # outward winding: face normals agree with the radial direction
    centroid = m.vertices[m.faces].mean(1) - c
    assert np.all(np.einsum("fk,fk->f", m.face_normals, centroid) > 0)
    assert np.all(np.abs(_uv_areas(m)) > 0)
    theta = np.arccos(np.clip(d[:, 2] / r, -1, 1))
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    body = (theta > 1e-9) & (theta < np.pi - 1e-9) & (m.uv[:, 0] < 1)
    np.testing.assert_allclose(m.uv[body, 0], phi[body] / (2 * np.pi), atol=1e-12)
    np.testing.assert_allclose(m.uv[:, 1], 1 - theta / np.pi, atol=1e-9)
    seam = m.uv[:, 0] == 1
    assert seam.sum() == 11 and np.allclose(phi[seam], 0)            # the duplicated seam column
    # closed after welding, volume close to the analytic one
    welded = trimesh.Trimesh(m.vertices, m.faces)
    assert welded.is_watertight and welded.is_winding_consistent
    assert welded.volume == pytest.approx(4 / 3 * math.pi * r**3, rel=0.05)
    assert Mesh.sphere(r, center=c, rings=12, segments=24) == m


def test_bowl_is_a_closed_non_convex_shell_that_shadows_itself():
    m = Mesh.bowl(radius=1.0, depth=0.5, thickness=0.05, rings=8, segments=24)
    lo, hi = m.bounds
    np.testing.assert_allclose(lo, [-1, -1, 0], atol=1e-12)
    np.testing.assert_allclose(hi, [1, 1, 0.55], atol=1e-12)
    assert np.all(np.einsum("fk,fk->f", m.face_normals, m.normals[m.faces].mean(1)) > 0)
    assert m.uv.min() >= 0 and m.uv.max() <= 1 and np.all(np.abs(_uv_areas(m)) > 0)
    welded = trimesh.Trimesh(m.vertices, m.faces)
    assert welded.is_watertight and welded.is_winding_consistent and welded.volume > 0
    assert welded.convex_hull.volume > 3 * welded.volume                # far from convex
    # grazing light from +x: front-facing points inside the bowl are shadowed by the far rim;
    # a convex shape never shadows a front-facing point
    light = np.array([math.cos(math.radians(15)), 0.0, math.sin(math.radians(15))])
    inner = np.flatnonzero((m.normals[:, 2] > 0.3) & (m.vertices[:, 2] < 0.5)
                           & (m.normals @ light > 0.05))
    t = _ray_hits(m.vertices[inner] + 1e-7 * m.normals[inner], np.tile(light, (len(inner), 1)), m.vertices, m.faces)
    assert np.isfinite(t).sum() > 0.3 * len(inner)
    bottom = np.flatnonzero(np.isclose(m.vertices[:, 2], 0.05) & (m.normals[:, 2] > 0.99))
    assert len(bottom) and np.all(np.isfinite(_ray_hits(m.vertices[bottom] + 1e-7, np.tile(light, (len(bottom), 1)),
                                                        m.vertices, m.faces)))


def test_block_on_plane_geometry_and_analytic_shadow():
    size, (bx, by, bz) = 2.0, (0.5, 0.4, 0.6)
    m = Mesh.block_on_plane(size, (bx, by, bz))
    assert m.num_faces == 12
    np.testing.assert_allclose(m.bounds[0], [-1, -1, 0])
    np.testing.assert_allclose(m.bounds[1], [1, 1, bz])
    # every face points away from the box centre (ground: up)
    centroid = m.vertices[m.faces].mean(1)
    box = centroid[:, 2] > 0
    out = centroid[box] - [0, 0, bz / 2]
    assert np.all(np.einsum("fk,fk->f", m.face_normals[box], out) > 0)
    assert np.all(m.face_normals[~box] == [0, 0, 1]) and np.all(m.normals[m.faces].mean(1) == m.face_normals)
    # uv: a hand layout without overlaps and not mirrored
    assert np.all(_uv_areas(m) > 0) and _uv_areas(m).sum() < 1 and m.uv.min() >= 0 and m.uv.max() <= 1
    # ground points lit from low on +x: shadowed exactly where an analytic ray/box test says
    el = math.radians(25)
    light = np.array([math.cos(el), 0.0, math.sin(el)])
    rng = np.random.default_rng(2)
    p = np.concatenate([rng.uniform(-1, 1, (400, 2)), np.zeros((400, 1))], axis=1)
    p = p[(np.abs(p[:, 0]) > bx / 2 + 1e-3) | (np.abs(p[:, 1]) > by / 2 + 1e-3)]   # not under the box
    shadow = np.isfinite(_ray_hits(p, np.tile(light, (len(p), 1)), m.vertices, m.faces, eps=1e-9))
    analytic = (np.abs(p[:, 1]) < by / 2) & (p[:, 0] < -bx / 2) & (p[:, 0] > -bx / 2 - bz / math.tan(el))
    assert analytic.sum() > 5
    np.testing.assert_array_equal(shadow, analytic)


def test_shapes_are_deterministic_and_validate():
    for make in (lambda: Mesh.sphere(rings=6, segments=10), lambda: Mesh.bowl(rings=4, segments=12),
                 lambda: Mesh.block_on_plane(), lambda: Mesh.plane(1.0)):
        assert make().digest == make().digest
    assert len({Mesh.plane(1.0), Mesh.plane(1.0), Mesh.plane(2.0)}) == 2          # usable as dict keys
    for bad in (lambda: Mesh.sphere(-1.0), lambda: Mesh.sphere(rings=1), lambda: Mesh.bowl(thickness=2.0),
                lambda: Mesh.block_on_plane(2.0, (3.0, 0.5, 0.5)), lambda: Mesh.plane(0)):
        with pytest.raises(InputError) as e:
            bad()
        _one_line_error(e)


def test_xatlas_is_deterministic_and_keeps_faces():
    m = Mesh.block_on_plane()
    a, b = m.with_atlas(64, 2), m.with_atlas(64, 2)
    assert a == b and a.meta["atlas"]["padding"] == 2
    np.testing.assert_array_equal(a.vertices[a.faces], m.vertices[m.faces])
    np.testing.assert_array_equal(a.normals[a.faces], m.normals[m.faces])
    assert a.uv.min() >= 0 and a.uv.max() <= 1 and np.all(np.abs(_uv_areas(a)) > 0)


# ---------------------------------------------------------------- state
def test_state_round_trip_is_exact(tmp_path):
    from safetensors.torch import load_file, save_file

    m = Mesh.bowl(rings=3, segments=8)
    m = Mesh(m.vertices * 1.1, m.faces, m.uv, m.normals, name="odd", meta={"source": "x.obj", "atlas": {"padding": 2}})
    meta, tensors = m.to_state()
    path = tmp_path / "mesh.safetensors"
    save_file(tensors, str(path))
    back = Mesh.from_state(meta, load_file(str(path)))
    assert back == m and back.name == "odd" and back.meta == m.meta
    for k in ("vertices", "faces", "uv", "normals"):
        assert getattr(back, k).tobytes() == getattr(m, k).tobytes()
    with pytest.raises(InputError):
        Mesh.from_state({"format": "other"}, tensors)


def test_scene_parts_are_concatenated_with_node_transforms(tmp_path):
    from PIL import Image

    v, f, uv = _quad_file_mesh()
    turn = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 0, 1], point=[1, 2, 3])
    turn[:3, 3] += [5, 0, 0]

    def scene(images):
        s = trimesh.Scene()
        for k, im in enumerate(images):
            visual = TextureVisuals(uv=uv, image=im) if im is not None else TextureVisuals(uv=uv)
            s.add_geometry(trimesh.Trimesh(v, f, visual=visual, process=False), node_name=f"part{k}",
                           transform=turn if k else np.eye(4))
        return s

    path = tmp_path / "shared.glb"
    scene([None, None]).export(path)
    m = Mesh.load(path)
    assert m.meta["parts"] == 2 and m.meta["uv_source"] == "file" and m.num_faces == 6
    moved = trimesh.transformations.transform_points(v, turn)
    corners = {tuple(np.round(c, 5)) for c in m.vertices[m.faces].reshape(-1, 3)}
    assert corners == {tuple(np.round(c, 5)) for c in np.concatenate([v[f], moved[f]]).reshape(-1, 3)}
    path = tmp_path / "two_textures.glb"
    white, black = (Image.fromarray(np.full((4, 4, 3), c, np.uint8)) for c in (255, 0))
    scene([white, black]).export(path)
    m = Mesh.load(path, atlas_resolution=64)
    assert m.meta["uv_source"] == "xatlas" and "overlap" in m.meta["uv_note"] and m.num_faces == 6
