"""Render the Blender Cycles test files with Blender itself (the ``bpy`` wheel).

Usage::

    python tests/data/generate/cycles_files.py OUTDIR [NAME ...]

Writes tiny 32x32 multilayer EXR files, as Blender's own renderer writes them, into OUTDIR
(``tests/data/cycles`` for the committed copies). Without NAME every file is rendered; the
names are the keys of ``FILES``. The ``seed_K`` renders are independent replicates (Blender's
``seed`` property) for checking variances against the spread of means.

The scene: a ground plane, a glossy and a diffuse sphere, a point light and a grey world;
small enough that every file renders in well under a second on one core.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import bpy  # the whole script is Blender: run it with the bpy wheel installed


def _scene(*, samples: int, seed: int = 0, adaptive: bool = False, threshold: float = 0.01,
           time_limit: float = 0.0, denoise: bool = False, layer: str = "ViewLayer",
           stereo: bool = False, size: int = 32, passes: bool | None = None) -> bpy.types.Scene:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.seed = seed
    scene.cycles.use_adaptive_sampling = adaptive
    scene.cycles.adaptive_threshold = threshold
    scene.cycles.time_limit = time_limit
    scene.cycles.use_denoising = denoise
    scene.render.resolution_x = size
    scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 1
    bpy.ops.mesh.primitive_plane_add(size=10)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1, location=(-0.6, 0, 1))
    glossy = bpy.data.materials.new("glossy")
    glossy.use_nodes = True
    bsdf = glossy.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = 0.2
    bpy.context.object.data.materials.append(glossy)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(1.2, 0.5, 0.6))
    red = bpy.data.materials.new("red")
    red.use_nodes = True
    red.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.7, 0.15, 0.1, 1)
    bpy.context.object.data.materials.append(red)
    bpy.ops.object.light_add(type="POINT", location=(2, -2, 4))
    bpy.context.object.data.energy = 500
    bpy.context.object.data.shadow_soft_size = 0.5
    bpy.ops.object.camera_add(location=(0, -6, 3), rotation=(1.2, 0, 0))
    scene.camera = bpy.context.object
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[1].default_value = 0.5
    view_layer = scene.view_layers[0]
    view_layer.name = layer
    view_layer.cycles.pass_debug_sample_count = adaptive
    view_layer.cycles.denoising_store_passes = denoise if passes is None else passes  # Denoising Data
    if stereo:
        scene.render.use_multiview = True
        scene.render.views_format = "STEREO_3D"
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"
    if stereo:  # one multiview file (a part per view), not a file per view
        settings.views_format = "MULTIVIEW"
    return scene


def _render(scene: bpy.types.Scene, path: Path) -> None:
    scene.render.filepath = os.fspath(path)
    bpy.ops.render.render(write_still=True)


# name -> scene settings; every file is 32x32 and renders in well under a second.
FILES: dict[str, dict] = {
    # Blender's defaults as a user meets them: adaptive sampling and the denoiser on, so
    # Combined is denoised and Noisy Image holds the Monte Carlo mean.
    "cycles_default": dict(samples=64, adaptive=True, denoise=True),
    # Every pixel converges before the requested 512 samples: the render stops early (at 304
    # here) and the count pass is normalised by that, while the header says 512.
    "cycles_converged": dict(samples=512, adaptive=True, threshold=0.1),
    # The same scene asked for exactly 304 samples renders bit-identically to the previous one,
    # so its header is the truth for the samples the previous one took.
    "cycles_converged_304": dict(samples=304, adaptive=True, threshold=0.1),
    # Asked for 100 samples, off the convergence checks' grid (16, 32, ..., 96): the pixels that
    # do not converge stop at 100 itself, so the count pass is not all multiples of 16/100.
    "cycles_adaptive_100": dict(samples=100, adaptive=True, threshold=0.05),
    # The denoiser off and its passes stored (albedo, normal, depth: what --guide needs): Combined
    # is the Monte Carlo mean, and Blender writes no Noisy Image pass.
    "cycles_features": dict(samples=16, adaptive=True, passes=True),
    # A time limit stops the render long before the 4096 samples requested.
    "cycles_time_limit": dict(samples=4096, adaptive=True, threshold=0.01, time_limit=1.0),
    # Adaptive sampling on but no count pass: awr must warn.
    "cycles_adaptive_nocount": dict(samples=64, adaptive=True, threshold=0.05),
    # A view layer name with a dot.
    "cycles_layer_dot": dict(samples=16, adaptive=True, layer="beauty.main"),
    # Stereo: one part per view.
    "cycles_stereo": dict(samples=16, stereo=True),
    # Plain fixed-count renders with different seeds (independent replicates).
    **{f"cycles_seed_{k}": dict(samples=16, seed=k) for k in range(1, 9)},
    # A high-sample reference of the same scene.
    "cycles_ref": dict(samples=2048),
}


def render(name: str, outdir: Path, **overrides) -> Path:
    """Render one of ``FILES`` into ``outdir`` (settings overridden by ``overrides``)."""
    settings = dict(FILES[name]) | overrides
    nocount = name == "cycles_adaptive_nocount"
    scene = _scene(**settings)
    if nocount:
        scene.view_layers[0].cycles.pass_debug_sample_count = False
    path = outdir / f"{name}.exr"
    _render(scene, path)
    return path


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    outdir = Path(argv[0])
    outdir.mkdir(parents=True, exist_ok=True)
    for name in argv[1:] or list(FILES):
        if name not in FILES:
            print(f"unknown file {name!r}; choose from {', '.join(FILES)}", file=sys.stderr)
            return 2
        render(name, outdir)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
