"""Render the Mitsuba 3 test files with Mitsuba itself (the ``mitsuba`` wheel, llvm_ad_rgb).

Usage::

    python tests/data/generate/mitsuba_files.py OUTDIR [NAME ...] [--seeds FIRST:LAST NAME]

Writes tiny 32x32 (16x16 for the variations) EXR files as Mitsuba 3 writes them into OUTDIR (``tests/data/mitsuba`` for
the committed copies). Without NAME every file of ``FILES`` is rendered. ``--seeds 1:40 box``
renders the ``box`` scene once per seed into ``box_seed_K.exr`` (independent replicates, for
checking variances against the spread of means).

The scene is Mitsuba's own ``mi.cornell_box()`` with the ``moment`` integrator around a path
tracer (max_depth 6). ``mitsuba_cli_box`` is rendered by the ``mitsuba`` executable from an
XML scene file, the others through the Python API.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import mitsuba as mi  # the whole script is Mitsuba: run it with the mitsuba wheel installed

VARIANT = "llvm_ad_rgb"
SIZE = 32

# name -> (integrator, film filter, spp)
FILES: dict[str, tuple[str, str, int]] = {
    "mitsuba_box": ("moment", "box", 8),            # the supported setting
    "mitsuba_gaussian": ("moment", "gaussian", 8),  # mi.cornell_box()'s own filter
    "mitsuba_aov": ("moment_aov", "box", 8),        # moment around an aov integrator
    "mitsuba_ref": ("path", "box", 4096),           # high-sample reference (plain RGB)
    # Variations that real renders differ by (16x16, the readers' routes only):
    "mitsuba_mono": ("moment", "box", 8),           # a mono variant: X = Y = Z in every moment
    "mitsuba_half_aov": ("moment_aov", "box", 16),  # float16: subnormal normals, underflowed E[x^2]
    "mitsuba_uint32": ("path", "box", 8),           # component_format uint32: fixed point, clamped
    "mitsuba_mitchell": ("moment", "mitchell", 8),  # a filter with negative lobes: E[x^2] < 0
    "mitsuba_aov_position": ("moment_aov_position", "box", 8),  # AOVs with X,Y,Z nested in m2_main
    "mitsuba_aov_of_moment": ("aov_of_moment", "box", 8),       # img.m2_nested: moment inside aov
    "mitsuba_two": ("moment_two", "box", 8),        # two nested integrators: two radiance moments
    "mitsuba_xyz": ("path", "box", 8),              # pixel_format xyz: an image of X,Y,Z
    "mitsuba_narrow_gaussian": ("moment", "narrow_gaussian", 8),  # a filter within the pixel: unequal weights
    "mitsuba_spp1": ("moment", "box", 1),           # one sample per pixel: every second moment its mean squared
    "mitsuba_mono_aov": ("moment_aov", "box", 8),   # a mono variant's moment around an aov integrator: features
    "mitsuba_raw": ("moment", "box", 8),            # film.bitmap(raw=True): weighted sums beside their weights W
    "mitsuba_aov_no_radiance": ("moment_aov_no_radiance", "box", 8),  # aov without a radiance integrator: all 0
}
RAW = ("mitsuba_raw",)
"""Files written from the film's unnormalised bitmap rather than by ``film.write()``."""
RFILTERS: dict[str, dict] = {"narrow_gaussian": {"type": "gaussian", "stddev": 0.1}}
"""Filters with parameters, by the name ``FILES`` gives; any other name is the filter's type with its defaults."""
# name -> (variant, film options) where they differ from VARIANT and the film's defaults
OPTIONS: dict[str, tuple[str, dict]] = {
    "mitsuba_mono": ("llvm_ad_mono", {}),
    "mitsuba_mono_aov": ("llvm_ad_mono", {}),
    "mitsuba_half_aov": (VARIANT, {"component_format": "float16"}),
    "mitsuba_uint32": (VARIANT, {"component_format": "uint32"}),
    "mitsuba_xyz": (VARIANT, {"pixel_format": "xyz"}),
}
SMALL = 16
ORIGINAL = ("mitsuba_box", "mitsuba_gaussian", "mitsuba_aov", "mitsuba_ref")


def _integrator(kind: str) -> dict:
    path = {"type": "path", "max_depth": 6}
    if kind == "path":
        return path
    if kind == "moment":
        return {"type": "moment", "nested": path}
    if kind == "moment_aov_position":
        return {"type": "moment", "main": {"type": "aov", "aovs": "albedo:albedo,position:position,gn:geo_normal",
                                           "img": path}}
    if kind == "aov_of_moment":
        return {"type": "aov", "aovs": "albedo:albedo,depth:depth,normal:sh_normal",
                "img": {"type": "moment", "nested": path}}
    if kind == "moment_aov_no_radiance":
        return {"type": "moment", "main": {"type": "aov", "aovs": "albedo:albedo,depth:depth,normal:sh_normal"}}
    if kind == "moment_two":
        return {"type": "moment", "a": path, "b": {"type": "direct"}}
    # The aov integrator's nested image is RGB: its moments need no colour conversion.
    return {"type": "moment", "main": {"type": "aov", "aovs": "albedo:albedo,depth:depth,normal:sh_normal",
                                       "img": path}}


def render(name: str, outdir: Path, *, seed: int = 0, kind: str | None = None, rfilter: str | None = None,
           spp: int | None = None) -> Path:
    """Render one file through the Python API; returns the file written."""
    variant, film = OPTIONS.get(name, (VARIANT, {}))
    mi.set_variant(variant)
    k, f, n = FILES.get(name, (None, None, None))
    kind, rfilter, spp = kind or k, rfilter or f, spp or n
    scene = mi.cornell_box()
    scene["integrator"] = _integrator(kind)
    size = SIZE if name in ORIGINAL else SMALL
    scene["sensor"]["film"].update(width=size, height=size, rfilter=RFILTERS.get(rfilter, {"type": rfilter}), **film)
    loaded = mi.load_dict(scene)
    mi.render(loaded, spp=spp, seed=seed)
    path = outdir / f"{name}.exr"
    sensor_film = loaded.sensors()[0].film()
    if name in RAW:
        sensor_film.bitmap(raw=True).write(os.fspath(path))
    else:
        sensor_film.write(os.fspath(path))
    return path


_XML = """<scene version="3.0.0">
  <integrator type="moment"><integrator type="path" name="nested"><integer name="max_depth" value="6"/></integrator></integrator>
  <sensor type="perspective">
    <float name="fov" value="19.5"/>
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="8"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{size}"/><integer name="height" value="{size}"/>
      <rfilter type="box"/></film>
  </sensor>
  <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.885809, 0.698859, 0.666422"/></bsdf>
  <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.570068, 0.0430135, 0.0443706"/></bsdf>
  <bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.105421, 0.37798, 0.076425"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale value="1, 1, 1"/><rotate x="1" angle="-90"/><translate y="-1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="90"/><translate y="1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><ref id="white"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="90"/><translate x="-1"/></transform><ref id="red"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><translate x="1"/></transform><ref id="green"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.23, 0.19, 0.19"/><rotate x="1" angle="90"/><translate y="0.99"/></transform>
    <emitter type="area"><rgb name="radiance" value="18.387, 13.9873, 6.75357"/></emitter></shape>
  <shape type="sphere"><point name="center" value="0.335, -0.7, 0.38"/><float name="radius" value="0.3"/><ref id="white"/></shape>
</scene>
"""


def render_cli(outdir: Path) -> Path:
    """``mitsuba_cli_box``: the same kind of file written by the ``mitsuba`` executable."""
    exe = shutil.which("mitsuba") or os.path.join(os.path.dirname(sys.executable), "mitsuba")
    scene = outdir / "mitsuba_cli_box.xml"
    scene.write_text(_XML.format(size=SIZE))
    out = outdir / "mitsuba_cli_box.exr"
    subprocess.run([exe, "-m", VARIANT, "-o", os.fspath(out), os.fspath(scene)], check=True,
                   stdout=subprocess.DEVNULL)
    scene.unlink()
    return out


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    outdir = Path(argv[0])
    outdir.mkdir(parents=True, exist_ok=True)
    rest = argv[1:]
    if rest[:1] == ["--seeds"]:
        first, last = (int(x) for x in rest[1].split(":"))
        for name in rest[2:]:
            for seed in range(first, last + 1):
                src = render(name, outdir, seed=seed)
                src.rename(outdir / f"{name}_seed_{seed}.exr")
        return 0
    for name in rest or [*FILES, "mitsuba_cli_box"]:
        if name == "mitsuba_cli_box":
            render_cli(outdir)
        elif name in FILES:
            render(name, outdir, seed=1)
        else:
            print(f"unknown file {name!r}; choose from {', '.join(FILES)}, mitsuba_cli_box", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
