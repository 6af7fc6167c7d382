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
           stereo: bool = False, size: int = 32, passes: bool | None = None, count: bool | None = None,
           energy: float = 500.0, depth: str = "32", codec: str = "ZIP", lightgroup: str | None = None,
           only_view: str | None = None, border: tuple[float, float, float, float] | None = None,
           second_layer: int | None = None) -> bpy.types.Scene:
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
    bpy.context.object.data.energy = energy
    if lightgroup is not None:  # the light's contribution also written as its own Combined_<group> pass
        bpy.context.object.lightgroup = lightgroup
    bpy.context.object.data.shadow_soft_size = 0.5
    bpy.ops.object.camera_add(location=(0, -6, 3), rotation=(1.2, 0, 0))
    scene.camera = bpy.context.object
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[1].default_value = 0.5
    view_layer = scene.view_layers[0]
    view_layer.name = layer
    view_layer.cycles.pass_debug_sample_count = adaptive if count is None else count
    if lightgroup is not None:
        view_layer.lightgroups.add(name=lightgroup)
    if second_layer is not None:  # a view layer "Second" with its own sample count (and count pass)
        second = scene.view_layers.new("Second")
        second.samples = second_layer
        second.cycles.pass_debug_sample_count = view_layer.cycles.pass_debug_sample_count
    view_layer.cycles.denoising_store_passes = denoise if passes is None else passes  # Denoising Data
    if stereo:
        scene.render.use_multiview = True
        scene.render.views_format = "STEREO_3D"
        if only_view is not None:  # one view rendered: a multiview file whose every part is that view
            for name in ("left", "right"):
                scene.render.views[name].use = name == only_view
    if border is not None:  # (min x, max x, min y, max y), not cropped: the rest of the frame is written as 0
        scene.render.use_border = True
        (scene.render.border_min_x, scene.render.border_max_x,
         scene.render.border_min_y, scene.render.border_max_y) = border
        scene.render.use_crop_to_border = False
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = depth
    settings.exr_codec = codec
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
    "cycles_adaptive_nocount": dict(samples=64, adaptive=True, threshold=0.05, count=False),
    # A view layer name with a dot.
    "cycles_layer_dot": dict(samples=16, adaptive=True, layer="beauty.main"),
    # Stereo: one part per view.
    "cycles_stereo": dict(samples=16, stereo=True),
    # Plain fixed-count renders with different seeds (independent replicates).
    **{f"cycles_seed_{k}": dict(samples=16, seed=k) for k in range(1, 9)},
    # A high-sample reference of the same scene.
    "cycles_ref": dict(samples=2048),
    # Half-float channels and a light bright enough that pixels exceed the half maximum: Blender
    # writes 65504 there (clamped), not Inf. Two seeds, for merge --independent.
    **{f"cycles_half_clamped_{k}": dict(samples=16, seed=k, energy=5e7, depth="16") for k in (1, 2)},
    # Adaptive sampling with a light group (Combined_key): --color names that pass, and its counts
    # are still the layer's Debug Sample Count. Two seeds, for merge --independent.
    **{f"cycles_lightgroup_{k}": dict(samples=64, seed=k, adaptive=True, threshold=0.05, lightgroup="key")
       for k in (1, 2)},
    # Stereo with one view enabled at a time: multiview files whose every part has view left (right).
    **{f"cycles_only_{v}": dict(samples=32, adaptive=True, threshold=0.1, stereo=True, only_view=v)
       for v in ("left", "right")},
    # Two view layers, the second rendered with 48 samples: a plane named in Second is counted by
    # Second's count pass and header.
    "cycles_two_layers": dict(samples=32, adaptive=True, threshold=0.05, second_layer=48),
    # DWAA (lossy) compression, two seeds.
    **{f"cycles_dwaa_{k}": dict(samples=16, seed=k, codec="DWAA") for k in (1, 2)},
    # A border render, not cropped, without the count pass: outside the border every channel is 0.
    "cycles_border_nocount": dict(samples=16, border=(0.25, 0.75, 0.0, 0.5)),
}


def render(name: str, outdir: Path, **overrides) -> Path:
    """Render one of ``FILES`` into ``outdir`` (settings overridden by ``overrides``)."""
    settings = dict(FILES[name]) | overrides
    scene = _scene(**settings)
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
