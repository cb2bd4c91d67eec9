"""Render the pictures of docs/blender.md that show what each option does, with the bpy module (headless, Workbench).

    .venv/bin/python tools/render_option_pictures.py                # into docs/images/
    .venv/bin/python tools/render_option_pictures.py --output DIR

One scene: a smooth tube (a finger, a tail) in a box cage of 20 vertices, 5 rings of 4. Each picture binds it with one
option value through the add-on of this repository (lbc_addon, as the Bind button does) and renders it, either bent
with the cage, or at rest with the influence of one cage vertex painted (Show Influence: dark blue none, red full).
The cage is drawn as a grey wireframe; a small sphere marks the cage vertex whose influence is shown.
"""

import argparse
import math
import os
import sys
from pathlib import Path

import bpy  # noqa: I001  (first: the add-on's modules import bpy's own)
import numpy as np
from mathutils import Vector

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
import lbc_addon  # noqa: E402
from lbc_addon import api, influence  # noqa: E402

SIZE = (480, 320)
RADIUS, HALF_HEIGHT = 0.32, 1.4  # the tube
CAGE_HALF_WIDTH, CAGE_HALF_HEIGHT, CAGE_RINGS = 0.6, 1.65, 5
BEND = math.radians(75)  # the pose: the cage bent by this angle over its height, towards +x
SHOWN = 14  # the cage vertex whose influence is painted: the front corner of the fourth ring (of five) from the base


def tube(rings=48, sides=32):
    """Vertices and faces of a closed tube along z, with rounded ends."""
    heights = np.linspace(-HALF_HEIGHT, HALF_HEIGHT, rings)
    ends = np.clip((np.abs(heights) - (HALF_HEIGHT - RADIUS)) / RADIUS, 0.0, 1.0)
    radii = RADIUS * np.sqrt(1.0 - ends ** 2 * 0.85)
    angles = np.linspace(0.0, 2 * math.pi, sides, endpoint=False)
    vertices = [(r * math.cos(a), r * math.sin(a), z) for z, r in zip(heights, radii) for a in angles]
    faces = [(ring * sides + i, ring * sides + (i + 1) % sides, (ring + 1) * sides + (i + 1) % sides,
              (ring + 1) * sides + i) for ring in range(rings - 1) for i in range(sides)]
    faces += [tuple(reversed(range(sides))), tuple((rings - 1) * sides + i for i in range(sides))]
    return vertices, faces


def box_cage():
    """Vertices and faces of a closed box around the tube, in rings of 4 vertices along z."""
    w = CAGE_HALF_WIDTH
    corners = [(-w, -w), (w, -w), (w, w), (-w, w)]
    heights = np.linspace(-CAGE_HALF_HEIGHT, CAGE_HALF_HEIGHT, CAGE_RINGS)
    vertices = [(x, y, z) for z in heights for x, y in corners]
    faces = [(ring * 4 + i, ring * 4 + (i + 1) % 4, (ring + 1) * 4 + (i + 1) % 4, ring * 4 + 4 + i)
             for ring in range(CAGE_RINGS - 1) for i in range(4)]
    faces += [(3, 2, 1, 0), tuple((CAGE_RINGS - 1) * 4 + i for i in range(4))]
    return vertices, faces


def bent(points):
    """The pose: points bent around an axis parallel to y, the bottom of the cage staying where it is."""
    points = np.asarray(points, dtype=float)
    length = 2 * CAGE_HALF_HEIGHT
    radius = length / BEND
    angle = (points[:, 2] + CAGE_HALF_HEIGHT) / radius
    out = points.copy()
    out[:, 0] = radius - (radius - points[:, 0]) * np.cos(angle)
    out[:, 2] = -CAGE_HALF_HEIGHT + (radius - points[:, 0]) * np.sin(angle)
    return out


def add_object(name, vertices, faces, color):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in vertices], [], faces)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    material = bpy.data.materials.new(name)
    material.diffuse_color = color
    mesh.materials.append(material)
    return obj


def build_scene():
    """The tube, its cage (hidden in renders, drawn by a wireframe copy), a marker, a camera; returns them."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types.Object, "lbc"):
        lbc_addon.register()
    scene = bpy.context.scene
    tube_obj = add_object("Tube", *tube(), (0.85, 0.62, 0.42, 1.0))
    tube_obj.data.shade_smooth()
    cage = add_object("Cage", *box_cage(), (0.5, 0.5, 0.5, 1.0))
    cage.hide_render = True
    wire = bpy.data.objects.new("Cage Wireframe", cage.data)  # shares the cage's data, so it shows the pose
    wire.modifiers.new("Wireframe", "WIREFRAME").thickness = 0.015
    scene.collection.objects.link(wire)
    marker = add_object("Marker", *sphere(0.07), (0.95, 0.95, 0.95, 1.0))
    marker.data.shade_smooth()

    # The tube lies across the picture, its base on the left, bending upwards: the camera looks from +y, a little
    # from above the bend, with its right along +z.
    studio(scene, ortho_scale=4.6, target=Vector((0.6, 0.0, 0.0)), offset=Vector((2.5, 10.0, -1.5)), up="X")
    return tube_obj, cage, marker


def studio(scene, ortho_scale, target, offset, up):
    """The pictures' look: a dark world, Workbench at SIZE with studio light and 8× anti-aliasing, and an orthographic
    camera at ``target + offset`` looking at ``target``, its ``up`` axis ("X" or "Y") up in the picture."""
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.02, 0.022, 0.026)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100
    scene.display.shading.light = "STUDIO"
    scene.display.shading.show_cavity = False
    scene.display.render_aa = "8"
    scene.view_settings.view_transform = "Standard"
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = ortho_scale
    camera.location = target + offset
    camera.rotation_euler = (target - camera.location).to_track_quat("-Z", up).to_euler()


def sphere(radius, rings=8, sides=12):
    """A small UV sphere's vertices and faces, at the origin."""
    vertices = [(0.0, 0.0, -radius)]
    for ring in range(1, rings):
        theta = math.pi * ring / rings - math.pi / 2
        vertices += [(radius * math.cos(theta) * math.cos(phi), radius * math.cos(theta) * math.sin(phi),
                      radius * math.sin(theta)) for phi in np.linspace(0, 2 * math.pi, sides, endpoint=False)]
    vertices.append((0.0, 0.0, radius))
    top = len(vertices) - 1
    faces = [(0, 1 + (i + 1) % sides, 1 + i) for i in range(sides)]
    faces += [(1 + r * sides + i, 1 + r * sides + (i + 1) % sides, 1 + (r + 1) * sides + (i + 1) % sides,
               1 + (r + 1) * sides + i) for r in range(rings - 2) for i in range(sides)]
    faces += [(1 + (rings - 2) * sides + i, 1 + (rings - 2) * sides + (i + 1) % sides, top) for i in range(sides)]
    return vertices, faces


def pose(cage, posed):
    """Put the cage at rest or in the bent pose (as an edit of its vertices, which the mesh follows)."""
    rest = np.array(box_cage()[0], dtype=float)
    cage.data.vertices.foreach_set("co", (bent(rest) if posed else rest).astype(np.float32).ravel())
    cage.data.update()


def render(path, tube_obj, cage, marker, *, posed, influence_of=None):
    """Render the scene to ``path``: bent or at rest, with one cage vertex's influence painted or not."""
    scene = bpy.context.scene
    pose(cage, posed)
    marker.hide_render = influence_of is None
    if influence_of is not None:
        marker.location = cage.data.vertices[influence_of].co
        influence.show(tube_obj, influence_of)
        scene.display.shading.color_type = "VERTEX"
    else:
        scene.display.shading.color_type = "MATERIAL"
    bpy.context.view_layer.update()
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    small(path)
    if influence_of is not None:
        influence.hide(tube_obj)
    pose(cage, False)
    print(f"{path}: {path.stat().st_size / 1e3:.0f} kB")


def small(path):
    """Rewrite a PNG with a palette of 256 colours: half the size, the same to the eye (Pillow comes with
    matplotlib, in the dev extra)."""
    from PIL import Image

    with Image.open(path) as image:
        palette = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    palette.save(path, optimize=True)


def bind(tube_obj, cage, **options):
    """Bind the tube to the cage at rest, as the Bind button does, with these options."""
    pose(cage, False)
    summary = api.bind(tube_obj, cage, from_scratch=True, progress=lambda fraction, message: None, **options)
    print(f"bound with {options or 'the defaults'}: {summary.mean_influences:.1f} influences per vertex (mean)")
    return summary


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "images",
                        help="where the PNG files go (default: docs/images)")
    args = parser.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    tube_obj, cage, marker = build_scene()
    out = args.output

    def picture(name, **how):
        render(out / f"option-{name}.png", tube_obj, cage, marker, **how)

    # Defaults: the bent tube, Show Influence, Strength and Vertex Group (modifier inputs: no new bind).
    bind(tube_obj, cage)
    picture("bent", posed=True)
    picture("show-influence", posed=False, influence_of=SHOWN)
    picture("show-influence-bent", posed=True, influence_of=SHOWN)
    for strength in (0.0, 0.5):
        api.set_deformer(tube_obj, strength=strength)
        picture(f"strength-{strength:g}", posed=True)
    api.set_deformer(tube_obj, strength=1.0)
    group = tube_obj.vertex_groups.new(name="Tip")
    heights = np.array([vertex.co.z for vertex in tube_obj.data.vertices])
    weights = np.clip((heights + 0.2) / 0.8, 0.0, 1.0)  # 0 below the middle, rising to 1 over the upper part
    for index, weight in enumerate(weights):
        group.add([index], float(3 * weight ** 2 - 2 * weight ** 3), "REPLACE")
    api.set_deformer(tube_obj, vertex_group="Tip")
    picture("vertex-group", posed=True)
    api.set_deformer(tube_obj, invert_vertex_group=True)
    picture("vertex-group-inverted", posed=True)
    api.set_deformer(tube_obj, vertex_group="", invert_vertex_group=False)

    # Bind options: each value is a new bind; the influence of one cage vertex shows what changes.
    for thinning in (1e-9, 0.06):
        bind(tube_obj, cage, thinning=thinning)
        picture(f"thinning-{thinning:g}", posed=False, influence_of=SHOWN)
    for influences in (6, 3):
        bind(tube_obj, cage, influences=influences)
        picture(f"max-influences-{influences}-bent", posed=True)
        if influences == 3:
            picture(f"max-influences-{influences}", posed=False, influence_of=SHOWN)
    for epsilon in (0.01, 1.0):
        bind(tube_obj, cage, epsilon=epsilon)
        picture(f"relaxation-{epsilon:g}", posed=False, influence_of=SHOWN)
    for smoothness in (0.0, 1.0):
        bind(tube_obj, cage, smoothness=smoothness)
        picture(f"smoothness-{smoothness:g}", posed=False, influence_of=SHOWN)
        picture(f"smoothness-{smoothness:g}-bent", posed=True)


if __name__ == "__main__":
    main()
    # The bpy module of Blender 4.5 can hang at interpreter exit once an add-on is registered (see tests/conftest.py).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
