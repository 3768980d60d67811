"""Mitsuba's LLVM CPU variant works after the project's setup (libllvm19 + DRJIT_LIBLLVM_PATH)."""
import subprocess
import sys

import pytest


@pytest.mark.needs_llvm
def test_llvm_variant_renders_in_a_subprocess():
    # a subprocess, because a wrong LLVM aborts the whole process
    code = (
        "from bayes_brdf.mitsuba_env import import_mitsuba\n"
        "mi = import_mitsuba('llvm_ad_rgb')\n"
        "scene = mi.load_dict({'type': 'scene', 'integrator': {'type': 'path'}, 'rect': {'type': 'rectangle', 'bsdf': {'type': 'diffuse'}},"
        " 'light': {'type': 'constant'}, 'sensor': {'type': 'perspective', 'fov': 40,"
        " 'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),"
        " 'film': {'type': 'hdrfilm', 'width': 8, 'height': 8}}})\n"
        "import numpy as np\n"
        "img = np.array(mi.render(scene, spp=4))\n"
        "print(float(img[4, 4, 0]))\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    # a white-ish diffuse plane under a unit constant environment reflects about its albedo (0.5)
    assert 0.3 < float(p.stdout.strip().splitlines()[-1]) < 0.7
