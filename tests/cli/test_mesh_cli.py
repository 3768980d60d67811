"""The CLI on a mesh capture, as a user runs it: render a transforms.json capture of a bowl, then infer, fit with
held-out views and recommend new perspective views around it."""
import json

import pytest

from bayes_brdf.cli.main import main
from bayes_brdf.posterior import Posterior
from bayes_brdf.render.mesh import Mesh

pytestmark = pytest.mark.needs_llvm


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("bowl")
    assert main(["render", "tiles", "--mesh", "bowl", "--views", "fibonacci:6", "--resolution", "24",
                 "--out", str(out)]) == 0
    assert (out / "transforms.json").is_file()
    return out


def test_infer_fit_and_recommend_on_a_mesh_capture(capture, tmp_path, capsys):
    assert main(["infer", str(capture), "--steps", "60", "--particles", "4", "--out", str(tmp_path / "inf")]) == 0
    post = Posterior.load(tmp_path / "inf" / "posterior.safetensors")
    assert isinstance(post.surface, Mesh) and post.surface.name == "bowl"
    assert post.particles["albedo"].shape == (4, 3, 24, 24)          # texels of the mesh's atlas
    assert main(["fit", str(capture), "--holdout", "5", "--steps", "60", "--particles", "4",
                 "--out", str(tmp_path / "fit")]) == 0
    s = json.loads((tmp_path / "fit" / "summary.json").read_text())
    assert s["heldout_views"] == [5] and 0 <= s["heldout"]["coverage"]["90"] <= 1
    assert (tmp_path / "fit" / "heldout" / "view_05_std.png").is_file()
    assert main(["recommend", str(capture), "--posterior", str(tmp_path / "inf" / "posterior.safetensors"),
                 "--candidates", "fibonacci:40", "--k", "2", "--out", str(tmp_path / "rec")]) == 0
    rec = json.loads((tmp_path / "rec" / "recommend.json").read_text())
    assert len(rec["indices"]) == 2
    assert all(v["camera"]["type"] == "perspective" for v in rec["views"])   # cameras that can see a mesh
    assert (tmp_path / "rec" / "candidates.png").is_file()
