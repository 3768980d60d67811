"""Ship the top-level preset folders (models/, samplers/) inside the wheel (TOML presets and decoder weights).

They stay plain TOML folders at the repository root (not importable packages);
at build time they are copied to ``bayes_brdf/presets/<folder>/`` in the wheel.
An editable install finds them at the repository root instead
(see ``bayes_brdf.presets``).
"""
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).parent
PRESET_DIRS = ("models", "samplers")


class BuildWithPresets(build_py):
    def run(self):
        super().run()
        for folder in PRESET_DIRS:
            src = ROOT / folder
            dst = Path(self.build_lib) / "bayes_brdf" / "presets" / folder
            dst.mkdir(parents=True, exist_ok=True)
            for f in sorted([*src.glob("*.toml"), *src.glob("*.safetensors")]):
                self.copy_file(str(f), str(dst / f.name))


setup(cmdclass={"build_py": BuildWithPresets})
