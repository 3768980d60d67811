"""The ``bayes-brdf`` command line.

Commands (``bayes-brdf COMMAND --help`` for each):

* ``render MATERIAL``  -- shade a procedural material or a maps folder under
  generated views (or a capture's views) and write an observation bundle
  (images + ``observations.json``) plus sRGB previews; with ``--mesh``, on a
  mesh, written as a ``transforms.json`` capture.
* ``inspect CAPTURE``  -- what a capture (any supported format) contains.
* ``infer CAPTURE``    -- sample the posterior of a material model with any sampler
  (name or preset file); writes the posterior, mean and std maps.
* ``fit CAPTURE``      -- fit on some views, hold out the rest: uncertainty maps, held-out error,
  correlation and coverage numbers.
* ``fit-many CAPTURE...`` -- ``fit`` of each capture into its own folder (serial, or on Ray: ``--ray``).
* ``recommend CAPTURE`` -- rank candidate views (held-out or generated) by mutual information.
* ``demo``             -- the whole story on a synthetic material, with an HTML report.
* ``compare``          -- the sampler comparison table (the paper's Table 1).
* ``experiment NAME``  -- one of the paper's figures on synthetic data (``list`` shows them).
* ``train-decoder``    -- train the ``latent_decoder`` model's generator on the procedural materials.

Bad input prints ONE line ``bayes-brdf: error: ...`` and exits with code 2.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import time
from pathlib import Path

from .. import __version__
from ..errors import InputError
from . import compare as compare_cmd
from .common import positive_float, positive_int
from . import infer as infer_cmd
from . import experiment as experiment_cmd
from . import fit as fit_cmd
from . import fit_many as fit_many_cmd
from . import recommend as recommend_cmd
from . import demo as demo_cmd
from . import train_decoder as train_decoder_cmd


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2) instead of usage dumps."""

    def error(self, message):  # noqa: D401
        shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)   # one line, always
        self.exit(2, f"{self.prog}: error: {shown}; see '{self.prog} --help'\n")


_positive_int, _positive_float = positive_int, positive_float


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _views_from_spec(spec: str, a, target=(0.0, 0.0, 0.0)) -> list:
    from ..render.views import View, collocated_views, orbit_views

    p = Path(spec)
    if p.suffix.lower() == ".json" or p.exists():
        if not p.is_file():
            raise InputError("views file not found", where=p, fix="give fibonacci:N, sobol:N, random:N, orbit:N or a JSON file")
        try:
            data = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise InputError(f"unreadable views JSON ({e})", where=p) from None
        envs = {}
        if isinstance(data, dict) and data.get("environments"):       # a bundle's maps, next to its JSON
            from ..io.bundle import load_environments
            envs = load_environments(data, p)
        data = data.get("views", data) if isinstance(data, dict) else data
        if not isinstance(data, list) or not data:
            raise InputError("expected a non-empty list of views", where=p, fix="see observations.json written by 'render'")
        # a plain list of views, or the "views" of an observations.json bundle ({"view": {...}, "image": ...})
        return [View.from_dict(d.get("view", d) if isinstance(d, dict) else d, where=f"{p}[{i}]", environments=envs)
                for i, d in enumerate(data)]
    kind, _, num = spec.partition(":")
    if kind not in ("fibonacci", "sobol", "random", "orbit") or not num.isdigit() or int(num) < 1:
        raise InputError(f"bad --views '{spec}'", fix="use fibonacci:N, sobol:N, random:N, orbit:N or a JSON file of views")
    common = dict(camera=a.camera, resolution=a.resolution, fov=a.fov, power=a.power, target=target)
    if kind == "orbit":
        return orbit_views(int(num), a.radius, zenith=a.max_zenith / 2, **common)
    return collocated_views(int(num), a.radius, method=kind, max_zenith=a.max_zenith, seed=a.seed, **common)


def _load_material(name: str, a):
    """The material to render: a procedural one, a maps folder, or a metallic-roughness folder (``base_color``,
    ``metallic``, ``roughness``; :attr:`a.principled` then holds those maps, and the returned SVBRDF is what our
    renderer draws of them, :func:`~bayes_brdf.models.metallic.metallic_to_svbrdf`)."""
    from ..io import is_metallic_folder, load_metallic_maps, load_svbrdf
    from ..materials import MATERIALS, make_material

    a.principled = None
    if Path(name).is_dir() and is_metallic_folder(name):
        import torch

        from ..models.metallic import metallic_to_svbrdf
        t = load_metallic_maps(name)
        a.principled = t
        return metallic_to_svbrdf(t["base_color"], t["metallic"], t["roughness"],
                                  torch.zeros_like(t["base_color"])).with_flat_normals()
    if Path(name).is_dir():
        return load_svbrdf(name)
    if name not in MATERIALS:
        raise InputError(f"'{name}' is neither a procedural material nor a maps folder",
                         fix=f"use one of {', '.join(sorted(MATERIALS))} or a folder with albedo/roughness/specular/normal maps")
    return make_material(name, a.resolution or 128, seed=a.seed)


_BUILTIN_MESHES = ("sphere", "bowl", "block", "plane")


def _load_mesh(spec: str, a):
    """``--mesh``: a mesh file (with ``--mesh-units`` / ``--mesh-up``) or a built-in shape name."""
    from ..render.mesh import Mesh

    p = Path(spec)
    if p.is_file():
        return Mesh.load(p, units=a.mesh_units, up=a.mesh_up)
    if spec in _BUILTIN_MESHES:
        return {"sphere": Mesh.sphere, "bowl": Mesh.bowl, "block": Mesh.block_on_plane, "plane": Mesh.plane}[spec]()
    raise InputError(f"--mesh {spec!r} is neither a mesh file nor a built-in shape",
                     fix=f"give an OBJ/PLY/GLB file or one of {', '.join(_BUILTIN_MESHES)}")


def _with_environment(views, a) -> list:
    """``--env`` / ``--env-rotate`` / ``--env-scale`` / ``--no-flash`` applied to the views' lights."""
    from ..render.environment import EnvironmentLight, z_up
    from ..render.views import View

    if not a.env:
        for opt, val in (("--env-rotate", a.env_rotate), ("--env-scale", a.env_scale)):
            if val is not None:
                raise InputError(f"{opt} needs --env", fix=f"add --env MAP.exr, or leave {opt} out")
    env = None
    if a.env:
        env = EnvironmentLight.from_file(a.env, a.env_scale if a.env_scale is not None else 1.0,
                                         z_up(a.env_rotate or 0.0))
    out = []
    for v in views:
        lights = [l for l in v.lights if env is None or not isinstance(l, EnvironmentLight)]   # --env replaces
        if a.no_flash:
            lights = [l for l in lights if isinstance(l, EnvironmentLight)]
        if env is not None:
            lights.append(env)
        if not lights:
            raise InputError(f"--no-flash leaves view '{v.name}' without a light",
                             fix="add --env MAP.exr (an environment light), or leave --no-flash out")
        out.append(View(v.camera, tuple(lights), v.name))
    return out


def _check_integrator(a) -> None:
    """``--integrator`` with ``--spp`` / ``--max-depth``: one line for a combination that does not apply."""
    if a.integrator == "ours":
        for opt, val in (("--spp", a.spp), ("--max-depth", a.max_depth)):
            if val is not None:
                raise InputError(f"{opt} applies to Mitsuba's integrators", fix="add --integrator path (or direct)")
        return
    if a.camera == "rectified" and not a.capture:
        raise InputError(f"--integrator {a.integrator} renders through Mitsuba's perspective camera",
                         fix="use --camera perspective (the default)")
    if a.integrator == "direct" and a.max_depth is not None:
        raise InputError("--max-depth applies to --integrator path", fix="leave it out, or use --integrator path")
    a.spp = a.spp or 64
    a.max_depth = a.max_depth or 8


#: the independent batches a Mitsuba render is split into to estimate each pixel's own variance
VARIANCE_BATCHES = 8


def _variance_batches(spp: int) -> int:
    """The batches of ``spp`` samples that estimate a render's variance: the most of 8, 4, 2 that divide ``spp``
    into at least two samples each (1: ``spp`` too small, no variance).

    Example:
        >>> _variance_batches(64), _variance_batches(12), _variance_batches(3)
        (8, 4, 1)
    """
    return next((b for b in (VARIANCE_BATCHES, 4, 2) if spp % b == 0 and spp >= 2 * b), 1)


def _mitsuba_view(maps, view, surface, a, k: int):
    """One view ``([H, W, 3], its Monte Carlo variance [H, W, 3] or None)`` rendered by Mitsuba (``--integrator
    direct|path``, a perspective sensor with a box filter: pixel areas): a plane as the two-triangle mesh of
    the same square; the variance from independent batches of the samples (:func:`_variance_batches`)."""
    from ..render.mesh import Mesh
    from ..render.mitsuba_reference import render_reference
    from ..render.surface import PlanarSample

    from ..render.mitsuba_reference import render_principled

    mesh = Mesh.plane(surface.size) if isinstance(surface, PlanarSample) else surface
    b = _variance_batches(a.spp)
    kw = dict(camera="sensor", integrator=a.integrator, spp=a.spp, max_depth=a.max_depth, seed=a.seed + 104729 * k,
              batches=b)
    if getattr(a, "principled", None) is not None:      # a metallic-roughness material: Mitsuba's principled BSDF
        out = render_principled(a.principled, [view], mesh, **kw)
    else:
        out = render_reference(maps.to("cpu"), [view], mesh, **kw)
    if b == 1:                              # float rounding can leave a -1e-12 (principled): radiance is >= 0
        return out[0].float().clamp_min(0), None
    return out[0][0].float().clamp_min(0), out[1][0].float()


def cmd_render(a) -> int:
    import torch
    from tqdm import tqdm

    from ..io import load_capture, save_observations, save_svbrdf, save_transforms, write_exr, write_png
    from ..observations import Observations
    from ..render.gbuffer import GBuffer
    from ..render.shade import shade
    from ..render.surface import PlanarSample
    from ..io.outputs import check_folder

    if a.mesh and a.capture:
        raise InputError("--mesh and --capture both give the geometry", fix="use one of them")
    if a.mesh and a.camera == "rectified":
        raise InputError("--camera rectified cannot look at a --mesh (it only images the planar sample)",
                         fix="use --camera perspective")
    _check_integrator(a)
    check_folder(a.out)
    transforms = False
    if a.capture:
        cap = load_capture(a.capture, resolution=a.resolution, max_resolution=128)
        views, surface = cap.views, cap.surface
        a.resolution = a.resolution or cap.resolution[0]
        transforms = cap.meta.get("format") == "transforms"
    elif a.mesh:
        surface = _load_mesh(a.mesh, a)
        a.resolution = a.resolution or 128
        a.radius = a.radius or 3.0 * surface.radius      # the bounding sphere spans ~85% of a 45-degree fov
        a.power = a.power or 20.0 * (a.radius / 3.0) ** 2   # as bright as the default planar sample
        views = _views_from_spec(a.views, a, target=surface.center)
        transforms = True
    else:
        a.resolution = a.resolution or 128
        a.radius, a.power = a.radius or 3.0, a.power or 20.0
        views, surface = _views_from_spec(a.views, a), PlanarSample(a.sample_size)
    if a.layout != "auto":
        transforms = a.layout == "transforms"
    if transforms and isinstance(surface, PlanarSample):
        raise InputError("--layout transforms needs a mesh (a transforms.json capture stores perspective photos of "
                         "a mesh)", fix="add --mesh PATH|sphere|bowl|block|plane, or use --layout bundle")
    views = _with_environment(views, a)
    maps = _load_material(a.material, a).to(dtype=torch.float32, device=a.device)
    flattened = False
    if any(v.environment is not None for v in views):      # the environment's transfer follows the geometry only
        flat = maps.with_flat_normals()
        flattened = not torch.equal(maps.normal, flat.normal)
        maps = flat
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if len({tuple(v.resolution) for v in views}) > 1:
        raise InputError("the views have different resolutions", fix="render them in separate calls")
    images, variances = [], []
    t0 = time.perf_counter()
    with torch.no_grad():
        for k, v in enumerate(tqdm(views, desc="render", unit="view",
                                   disable=not sys.stderr.isatty() or len(views) < 4)):
            if a.integrator == "ours":
                g = GBuffer.build([v], surface, device=a.device)
                images.append(shade(maps, g)[0, 0].cpu())
            else:
                img, var = _mitsuba_view(maps, v, surface, a, k)
                images.append(img)
                if var is not None:
                    variances.append(var)
    per_view = (time.perf_counter() - t0) / max(1, len(views))
    imgs = torch.stack(images)
    meta = {"source": "bayes-brdf render", "material": a.material, "seed": a.seed, "units": "scene units",
            "integrator": a.integrator, "seconds_per_view": round(per_view, 3)}
    if a.integrator != "ours":
        meta.update(renderer=f"Mitsuba {a.integrator} integrator", spp=a.spp,
                    **({"max_depth": a.max_depth} if a.integrator == "path" else {}))
    if a.env:
        meta.update(environment=str(a.env), env_rotate=a.env_rotate or 0.0, env_scale=a.env_scale or 1.0)
    obs = Observations(views, imgs, surface, meta=meta, variance=torch.stack(variances) if variances else None)
    if transforms:
        jf = save_transforms(obs, out, image_format=a.format)
        written = f"transforms.json, images/*.{a.format}, {json.loads(jf.read_text())['mesh']}"
        if any(v.environment is not None for v in views):
            written += ", env*.exr"
    else:
        save_observations(obs, out, image_format=a.format)
        written = f"observations.json, {a.format.upper()} images"
    save_svbrdf(maps.to("cpu"), out / "maps")
    if getattr(a, "principled", None) is not None:       # the metallic-roughness maps it was made from
        for name, t in a.principled.items():
            write_exr(out / "maps" / f"{name}.exr", t.permute(1, 2, 0).contiguous())
    for i, im in enumerate(imgs):
        write_png(out / f"preview_{i:02d}.png", im.clamp(0, 1).numpy())
    what = f"'{a.material}'" + (f" on mesh '{surface.name}'" if not isinstance(surface, PlanarSample) else "")
    if getattr(a, "principled", None) is not None:
        what += " (metallic-roughness" + (": Mitsuba's principled BSDF)" if a.integrator != "ours" else
                                          ": our BRDF, kd = b (1 - m), F0 = lerp(0.04, b, m))")
    env = next((v.environment for v in views if v.environment is not None), None)
    if env is not None:
        what += f" under environment '{env.name or env.digest}'" + ("" if views[0].point_lights else " alone")
    how = "" if a.integrator == "ours" else \
        (f" with Mitsuba's {a.integrator} integrator ({a.spp} spp"
         + (f", max depth {a.max_depth}" if a.integrator == "path" else "") + f"; {per_view:.2f} s per view"
         + (f"; each pixel's render variance from {_variance_batches(a.spp)} batches" if variances else "") + ")")
    print(f"rendered {len(views)} views of {what}{how} at {imgs.shape[1]}x{imgs.shape[2]} -> {out}/ "
          f"({written}, preview_*.png, maps/)"
          + ("; the material's normal map was made flat (an environment light is shaded with the geometry's own "
             "normals)" if flattened else ""))
    return 0


def cmd_inspect(a) -> int:
    from ..io import describe, load_capture

    obs = load_capture(a.capture, resolution=a.resolution, fmt=a.format)
    print(describe(obs))
    return 0


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="bayes-brdf", description="Bayesian SVBRDF acquisition: posteriors, uncertainty, capture guidance.")
    p.add_argument("--version", action="version", version=f"bayes-brdf {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    r = sub.add_parser("render", help="render a material under views and write an observation bundle",
                       description="Render a procedural material (wood, tiles, marble, scratched_metal, leather, fabric) "
                                   "or a maps folder under generated views or a capture's views. Writes an observation "
                                   "bundle (observations.json + images), sRGB previews and the maps. With --mesh the "
                                   "material covers a mesh (through its uv), the views look at the mesh centre, and the "
                                   "result is a transforms.json capture (images, the mesh as OBJ) that inspect reads.")
    r.add_argument("material", help="procedural material name, a folder with albedo/roughness/specular/normal maps, or "
                                    "a metallic-roughness folder (base_color, metallic, roughness: rendered by "
                                    "Mitsuba's principled BSDF with --integrator direct|path)")
    src = r.add_mutually_exclusive_group()
    src.add_argument("--views", default="fibonacci:8",
                     help="fibonacci:N, sobol:N, random:N (collocated, hemisphere), orbit:N, or a JSON file of views "
                          "(default: %(default)s)")
    src.add_argument("--capture", help="render at the views (poses, lights, sample size) of this capture instead")
    r.add_argument("--mesh", metavar="PATH|SHAPE",
                   help="render on a mesh: an OBJ/PLY/GLB/glTF file, or a built-in shape (sphere, bowl, block, plane); "
                        "writes a transforms.json capture")
    r.add_argument("--mesh-units", choices=["mm", "cm", "m", "in", "ft"], default=None,
                   help="length unit of the --mesh file (default: cm, the scene unit)")
    r.add_argument("--mesh-up", choices=["z", "y", "-y", "-z"], default="z",
                   help="up axis of the --mesh file, rotated to +z (default: %(default)s; most OBJ/glTF exports: y)")
    r.add_argument("--layout", choices=["auto", "bundle", "transforms"], default="auto",
                   help="what to write: an observation bundle or a transforms.json capture (default: %(default)s: "
                        "transforms with --mesh or a transforms.json --capture, else bundle)")
    r.add_argument("--seed", type=int, default=0, help="material and view-set seed (default: %(default)s)")
    r.add_argument("--resolution", type=_positive_int, default=None,
                   help="map and image resolution (default: 128; with --capture its photos' own, at most 128)")
    r.add_argument("--camera", choices=["perspective", "rectified"], default="perspective",
                   help="camera model for generated views (default: %(default)s)")
    r.add_argument("--radius", type=_positive_float, default=None,
                   help="camera distance to the sample centre (default: 3; with --mesh 3 x the mesh's bounding radius)")
    r.add_argument("--max-zenith", type=_positive_float, default=60.0, help="largest camera zenith angle in degrees (default: %(default)s)")
    r.add_argument("--fov", type=_positive_float, default=45.0, help="perspective field of view in degrees (default: %(default)s)")
    r.add_argument("--power", type=_positive_float, default=None,
                   help="flash power (radiance = f cos P / d^2) (default: 20; with --mesh 20 x (radius / 3)^2, as bright)")
    r.add_argument("--env", metavar="MAP", default=None,
                   help="also light every view by this environment map (equirectangular OpenEXR or Radiance .hdr, "
                        "linear RGB, as Mitsuba's envmap), its zenith on +z; replaces a --capture's own environment. "
                        "The material's normal map is made flat under it")
    r.add_argument("--env-rotate", type=float, default=None, metavar="DEG",
                   help="turn the environment about +z by this many degrees, counter-clockwise seen from above (default: "
                        "0: the map's centre column is the sky towards -x, its left and right edges towards +x)")
    r.add_argument("--env-scale", type=_positive_float, default=None, metavar="S",
                   help="multiply the environment map's radiance by S (default: 1)")
    r.add_argument("--no-flash", action="store_true",
                   help="leave the views' point lights (the flash) out: with --env, lit by the environment alone")
    r.add_argument("--integrator", choices=["ours", "direct", "path"], default="ours",
                   help="ours: this library's renderer (direct light with shadows, pixel centres: the model the "
                        "samplers fit); direct: Mitsuba's direct integrator; path: Mitsuba's path tracer "
                        "(interreflections, Monte Carlo noise): photos from a renderer that is not our forward "
                        "model. Mitsuba renders through its perspective sensor (pixel areas, box filter) with "
                        "our BRDF as its BSDF (default: %(default)s)")
    r.add_argument("--spp", type=_positive_int, default=None,
                   help="Mitsuba's samples per pixel (default: 64)")
    r.add_argument("--max-depth", type=_positive_int, default=None,
                   help="--integrator path: the longest path (2: direct light only; default: 8)")
    r.add_argument("--sample-size", type=_positive_float, default=2.0, help="side of the square sample (default: %(default)s)")
    r.add_argument("--format", choices=["exr", "png"], default="exr", help="image format of the bundle (default: %(default)s)")
    r.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default: %(default)s)")
    r.add_argument("--out", default="out/render", help="output folder (default: %(default)s)")
    r.set_defaults(func=cmd_render)

    i = sub.add_parser("inspect", help="show what a capture contains",
                       description="Load a capture (MaterialGAN, svbrdf-diff-renderer parameters.json / optim.json, "
                                   "a transforms.json of a mesh, or our observations.json bundle) and print views, "
                                   "resolution, poses, value ranges and saturated pixels.")
    i.add_argument("capture", help="capture folder (or its parameters.json / optim.json / observations.json / "
                                   "transforms.json)")
    i.add_argument("--resolution", type=_positive_int, default=None, help="resample to this resolution (default: native)")
    i.add_argument("--format", default="auto",
                   choices=["auto", "materialgan", "svbrdf-diff-renderer", "svbrdf-diff-renderer-optim", "bundle",
                            "transforms"],
                   help="capture format (default: %(default)s, detected from the files)")
    i.set_defaults(func=cmd_inspect)
    infer_cmd.add_parser(sub)
    fit_cmd.add_parser(sub)
    fit_many_cmd.add_parser(sub)
    recommend_cmd.add_parser(sub)
    demo_cmd.add_parser(sub)
    compare_cmd.add_parser(sub)
    experiment_cmd.add_parser(sub)
    train_decoder_cmd.add_parser(sub)
    return p


def _sigterm(signum, frame):
    raise KeyboardInterrupt   # the driver saves its checkpoint on it, as on Ctrl-C


class _StderrLines(logging.Handler):
    """Log records as ``bayes-brdf: message`` on the current ``sys.stderr`` (looked up per line)."""

    def emit(self, record):
        print(f"bayes-brdf: {record.getMessage()}", file=sys.stderr)


def _log_to_stderr():
    """The library's info lines (``resuming from step N of M ...``, progress of long work) on stderr."""
    lg = logging.getLogger("bayes_brdf")
    if not any(isinstance(h, _StderrLines) for h in lg.handlers):
        lg.addHandler(_StderrLines())
    lg.setLevel(logging.INFO)
    lg.propagate = False


def main(argv=None) -> int:
    parser = build_parser()
    try:
        a = parser.parse_args(argv)
    except SystemExit as e:        # --help (0) or a one-line usage error (2): a code, also when called in-process
        return int(e.code or 0)
    if not getattr(a, "command", None):
        parser.print_help()
        return 2
    _log_to_stderr()
    if threading_main():
        signal.signal(signal.SIGTERM, _sigterm)
    if hasattr(a, "device"):
        import torch

        try:
            torch.device(a.device)
        except (RuntimeError, ValueError):
            print(f"bayes-brdf: error: --device {a.device!r} is not a torch device; use cpu or cuda", file=sys.stderr)
            return 2
    if getattr(a, "device", "cpu").startswith("cuda") and not getattr(a, "ray_address", None):  # a cluster's GPUs
        import torch

        if not torch.cuda.is_available():
            print(f"bayes-brdf: error: --device {a.device}: no CUDA device here; use --device cpu", file=sys.stderr)
            return 2
    try:
        return a.func(a)
    except InputError as e:
        print(f"bayes-brdf: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        from ..samplers.driver import Interrupted

        if isinstance(e, Interrupted) and e.checkpoint is not None:
            print(f"bayes-brdf: interrupted at step {e.step} of {e.steps}; checkpoint saved to {e.checkpoint}; "
                  "rerun the same command to resume", file=sys.stderr)
        else:
            print("bayes-brdf: interrupted (no sampler was running, nothing to resume from: rerun the command)",
                  file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `bayes-brdf inspect X | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
