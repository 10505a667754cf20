"""Render small Blender Cycles multilayer EXR files through ``bpy``, as Blender writes them.

Run with a Python that has the ``bpy`` package (Blender as a Python module), never the
project's venv (see data/recipes/cycles/README.md)::

    /tmp/bpyenv/bin/python data/recipes/cycles/render_cycles.py OUT_DIR \
        [--res 128] [--spp 4,16] [--ref-spp 1024] [--threads 1] [--half] [--codec ZIP]
        [--blender-denoiser]

Writes ``OUT_DIR/cycles_spp<N>.exr`` for each level, ``OUT_DIR/cycles_ref.exr`` (the
reference) and ``OUT_DIR/scene.json`` (what the scene is, for checking conventions: the camera's
world matrix, the moving sphere's pixel position at frames 1, 2 and 3).

The scene: a checker floor, a red diffuse sphere, a mirror-like metal sphere that reflects an
emissive panel, and a small blue sphere moving (keyframed, linear) between frames 1 and 3,
rendered at frame 2 with motion blur off, so Cycles writes the ``Vector`` pass. Two view
layers: ``ViewLayer`` with denoising data (``Denoising Normal/Albedo/Depth``), ``Depth``,
``Normal``, ``Vector`` and ``Position``; ``Layer2`` with only ``Combined``, ``Depth``,
``Normal`` and ``Vector`` (no denoising data, no position) and without the red sphere. Cycles on the CPU, adaptive
sampling and denoising off (``Combined`` is the noisy image), fixed seed per level.

Only ``bpy``, ``mathutils`` and the standard library are imported: the script runs in
Blender's Python, which has no mcdenoise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import bpy  # type: ignore[import-not-found]
from bpy_extras.object_utils import world_to_camera_view  # type: ignore[import-not-found]
from mathutils import Vector  # type: ignore[import-not-found]

FULL_LAYER = "ViewLayer"
PLAIN_LAYER = "Layer2"
FRAME = 2
#: Where the moving sphere is at frames 1, 2, 3 (linear keys: constant velocity).
MOVER_KEYS = {1: (1.05, -0.9, 0.35), 2: (1.35, -0.9, 0.5), 3: (1.65, -0.9, 0.65)}


def _material(name: str, *, color=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, emission=0.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    bsdf = nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    if emission:
        bsdf.inputs["Emission Color"].default_value = (1.0, 0.95, 0.85, 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission
    return mat


def _checker_material() -> bpy.types.Material:
    mat = _material("floor", roughness=0.8)
    nt = mat.node_tree
    checker = nt.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 6.0
    checker.inputs["Color1"].default_value = (0.75, 0.72, 0.65, 1.0)
    checker.inputs["Color2"].default_value = (0.15, 0.2, 0.3, 1.0)
    nt.links.new(checker.outputs["Color"], nt.nodes.get("Principled BSDF").inputs["Base Color"])
    return mat


def _sphere(name: str, location, radius: float, mat) -> bpy.types.Object:
    bpy.ops.mesh.primitive_uv_sphere_add(
        segments=48, ring_count=24, radius=radius, location=location
    )
    obj = bpy.context.active_object
    obj.name = name
    bpy.ops.object.shade_smooth()
    obj.data.materials.append(mat)
    return obj


def build_scene(res: int, threads: int) -> bpy.types.Scene:
    """The scene described in the module docstring, at ``res``×``res``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.render.use_motion_blur = False
    scene.render.resolution_x = res
    scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.use_persistent_data = False
    scene.frame_start, scene.frame_end = 1, 3

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.06, 0.08, 1)
    scene.world = world

    bpy.ops.mesh.primitive_plane_add(size=12, location=(0, 0, 0))
    floor = bpy.context.active_object
    floor.name = "floor"
    floor.data.materials.append(_checker_material())

    red = _sphere("diffuse", (-1.3, 0.2, 0.6), 0.6, _material("red", color=(0.7, 0.12, 0.1)))
    # The red sphere in a collection of its own, which Layer2 excludes (layers differ).
    only_full = bpy.data.collections.new("only_full")
    scene.collection.children.link(only_full)
    for coll in list(red.users_collection):
        coll.objects.unlink(red)
    only_full.objects.link(red)
    _sphere(
        "metal",
        (0.2, 0.8, 0.75),
        0.75,
        _material("metal", color=(0.95, 0.93, 0.88), metallic=1.0, roughness=0.02),
    )
    mover = _sphere("mover", MOVER_KEYS[FRAME], 0.35, _material("blue", color=(0.1, 0.25, 0.8)))
    for frame, loc in MOVER_KEYS.items():
        mover.location = loc
        mover.keyframe_insert("location", frame=frame)
    _set_linear(mover)

    # An emissive panel above and behind the camera: out of the frame, lights the scene and
    # shows in the metal sphere (where Cycles' Denoising Albedo exceeds 1).
    bpy.ops.mesh.primitive_plane_add(size=2.5, location=(-1.0, -7.5, 4.5))
    panel = bpy.context.active_object
    panel.name = "panel"
    panel.rotation_euler = (math.radians(-120), 0.0, math.radians(-10))
    panel.data.materials.append(_material("emitter", color=(0, 0, 0), roughness=1.0, emission=25.0))

    bpy.ops.object.camera_add(location=(0.0, -6.0, 2.2))
    cam = bpy.context.active_object
    direction = Vector((0.0, 0.0, 0.55)) - cam.location
    cam.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    cam.data.lens = 35.0
    scene.camera = cam

    full = scene.view_layers[0]
    full.name = FULL_LAYER
    plain = scene.view_layers.new(PLAIN_LAYER)
    for layer in (full, plain):
        layer.use_pass_combined = True
        layer.use_pass_z = True
        layer.use_pass_normal = True
        layer.use_pass_vector = True
    plain.layer_collection.children["only_full"].exclude = True
    full.use_pass_position = True
    full.cycles.denoising_store_passes = True
    plain.cycles.denoising_store_passes = False
    scene.frame_set(FRAME)
    return scene


def _set_linear(obj: bpy.types.Object) -> None:
    """Linear interpolation on every key of ``obj`` (Blender 5's layered actions included)."""
    action = obj.animation_data.action
    curves = []
    if hasattr(action, "layers") and action.layers:
        for layer in action.layers:
            for strip in layer.strips:
                for bag in strip.channelbags:
                    curves.extend(bag.fcurves)
    elif hasattr(action, "fcurves"):
        curves.extend(action.fcurves)
    for fc in curves:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def render(scene: bpy.types.Scene, path: Path, spp: int, seed: int, half: bool, codec: str):
    """Render the current frame to the multilayer EXR ``path``; returns the wall seconds."""
    scene.cycles.samples = spp
    scene.cycles.seed = seed
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "16" if half else "32"
    settings.exr_codec = codec
    scene.render.filepath = str(path)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - t0


def scene_facts(scene: bpy.types.Scene) -> dict:
    """Ground truth for checking the file's conventions (see the module docstring)."""
    cam = scene.camera
    res_x, res_y = scene.render.resolution_x, scene.render.resolution_y
    mover = bpy.data.objects["mover"]
    pixels = {}
    for frame in MOVER_KEYS:
        scene.frame_set(frame)
        ndc = world_to_camera_view(scene, cam, mover.matrix_world.translation)
        # (x right, y down) pixel coordinates of the sphere's centre, pixel centres at +0.5.
        pixels[str(frame)] = [ndc.x * res_x, (1.0 - ndc.y) * res_y]
    scene.frame_set(FRAME)
    return {
        "blender": bpy.app.version_string,
        "frame": FRAME,
        "resolution": [res_x, res_y],
        "camera_matrix_world": [list(row) for row in cam.matrix_world],
        "camera_location": list(cam.matrix_world.translation),
        # Pinhole, sensor fit AUTO on a square image: focal length in pixels = lens/sensor * res.
        "camera_focal_px": cam.data.lens / cam.data.sensor_width * max(res_x, res_y),
        "layers": {
            FULL_LAYER: "denoising data, Depth, Normal, Vector, Position",
            PLAIN_LAYER: "Combined, Depth, Normal, Vector; no red sphere",
        },
        "mover_pixel_xy_down": pixels,
        "mover_radius": 0.35,
        "mover_location": [list(MOVER_KEYS[f]) for f in sorted(MOVER_KEYS)],
    }


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="output folder")
    p.add_argument("--res", type=int, default=128, help="square resolution (default 128)")
    p.add_argument("--spp", default="4,16", help="noisy levels, comma-separated (default 4,16)")
    p.add_argument("--ref-spp", type=int, default=1024, help="reference spp (default 1024)")
    p.add_argument("--threads", type=int, default=1, help="render threads (default 1)")
    p.add_argument("--half", action="store_true", help="half-float channels (default float)")
    p.add_argument("--codec", default="ZIP", help="EXR compression (default ZIP)")
    p.add_argument(
        "--blender-denoiser",
        action="store_true",
        help="run Blender's denoiser (OIDN): Combined is then denoised, Noisy Image is written",
    )
    args = p.parse_args(argv)
    try:
        levels = [int(s) for s in args.spp.split(",") if s.strip()]
    except ValueError:
        print(f"render_cycles: --spp must be integers like 4,16, got {args.spp!r}", file=sys.stderr)
        return 2
    if not levels or min([*levels, args.ref_spp, args.res, args.threads]) < 1:
        print("render_cycles: --spp, --ref-spp, --res and --threads must be >= 1", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(args.res, args.threads)
    if args.blender_denoiser:
        scene.cycles.use_denoising = True
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    facts = scene_facts(scene)
    facts["files"] = {}
    for i, spp in enumerate(levels):
        name = f"cycles_spp{spp}.exr"
        secs = render(scene, args.out / name, spp, seed=1 + i, half=args.half, codec=args.codec)
        facts["files"][name] = {"spp": spp, "seed": 1 + i, "seconds": round(secs, 2)}
        print(f"{name}: {spp} spp, {secs:.1f} s", flush=True)
    secs = render(
        scene,
        args.out / "cycles_ref.exr",
        args.ref_spp,
        seed=1000,
        half=args.half,
        codec=args.codec,
    )
    facts["files"]["cycles_ref.exr"] = {
        "spp": args.ref_spp,
        "seed": 1000,
        "seconds": round(secs, 2),
    }
    print(f"cycles_ref.exr: {args.ref_spp} spp, {secs:.1f} s", flush=True)
    (args.out / "scene.json").write_text(json.dumps(facts, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    # Blender's own interpreter passes its arguments before "--"; a plain Python with bpy does not.
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(argv))
