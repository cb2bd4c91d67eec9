"""Render the pictures of docs/blender.md's "Making a cage", with the bpy module (headless, Workbench).

    .venv/bin/python tools/render_cage_pictures.py                # into docs/images/
    .venv/bin/python tools/render_cage_pictures.py --output DIR

Blender's Suzanne, given a cage by Make Cage (``api.make_cage``, as the button does) with each option shown, bound to
it (``api.bind``, the defaults) and posed: its right ear raised and the top of its head pulled up, by moving cage
vertices. The cage is drawn as a grey wireframe (a copy of it with a Wireframe modifier: the cage itself is hidden in
renders). Prints the time each cage took and its vertex count.
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
sys.path.insert(0, str(ROOT / "tools"))
import lbc_addon  # noqa: E402
from lbc_addon import api  # noqa: E402
from render_option_pictures import small, studio  # noqa: E402

EAR_X = 0.75  # cage vertices beyond this x carry Suzanne's right ear (her left, on the picture's right)
EAR_LIFT = math.radians(30)
EAR_GROUP_X = 0.5  # the vertex group of the partial cage: her right ear and the side of her head
HEAD_TOP_Z, HEAD_PULL = 0.55, 0.25


def build_scene():
    """Suzanne (smooth), a camera in front of her, the light and the render settings; returns her object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if not hasattr(bpy.types.Object, "lbc"):
        lbc_addon.register()
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_monkey_add()
    suzanne = bpy.context.active_object
    suzanne.data.shade_smooth()
    material = bpy.data.materials.new("Skin")
    material.diffuse_color = (0.85, 0.62, 0.42, 1.0)
    suzanne.data.materials.append(material)
    studio(scene, ortho_scale=3.6, target=Vector((0.0, 0.0, 0.15)),
           offset=Vector((-3.0, -8.0, 2.5)), up="Y")  # in front of her face (-y), a little to her right, above
    scene.display.shading.color_type = "MATERIAL"
    return suzanne


def wireframe(cage):
    """A grey wireframe copy of ``cage`` that renders (sharing its data, so it shows its pose)."""
    wire = bpy.data.objects.new(f"{cage.name} Wireframe", cage.data)
    wire.matrix_world = cage.matrix_world
    wire.modifiers.new("Wireframe", "WIREFRAME").thickness = 0.012
    bpy.context.scene.collection.objects.link(wire)
    if not cage.data.materials:
        material = bpy.data.materials.new("Cage")
        material.diffuse_color = (0.55, 0.58, 0.62, 1.0)
        cage.data.materials.append(material)
    return wire


def posed(rest):
    """The pose of the pictures: the cage vertices beyond EAR_X turned up about the ear's root (the right ear raised),
    those above HEAD_TOP_Z pulled up."""
    out = np.array(rest, dtype=float)
    ear = out[:, 0] > EAR_X
    root = np.array([EAR_X, 0.0, 0.2])
    offsets = out[ear] - root
    turn = np.array([[math.cos(EAR_LIFT), 0.0, -math.sin(EAR_LIFT)], [0.0, 1.0, 0.0],
                     [math.sin(EAR_LIFT), 0.0, math.cos(EAR_LIFT)]])
    out[ear] = root + offsets @ turn.T
    top = out[:, 2] > HEAD_TOP_Z
    out[top, 2] += HEAD_PULL * (out[top, 2] - HEAD_TOP_Z) / (out[:, 2].max() - HEAD_TOP_Z)
    return out


def set_vertices(mesh, positions):
    mesh.vertices.foreach_set("co", np.asarray(positions, dtype=np.float32).ravel())
    mesh.update()


def render(path):
    bpy.context.view_layer.update()
    bpy.context.scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    small(path)
    print(f"{path}: {path.stat().st_size / 1e3:.0f} kB", flush=True)


def make(suzanne, **options):
    """A cage for Suzanne with ``options`` (Make Cage's), its wireframe shown; prints its time and vertex count."""
    made = api.make_cage([suzanne], progress=lambda fraction, message: None, **options)
    print(f"cage with {options or 'the defaults'}: {made.vertices} vertices (asked {made.asked_vertices}), "
          f"{made.attempts} attempt(s), {made.seconds:.1f} s", flush=True)
    return made.cage, wireframe(made.cage)


def drop(*objects):
    for obj in objects:
        bpy.data.objects.remove(obj)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "images",
                        help="where the PNG files go (default: docs/images)")
    args = parser.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    out = args.output
    suzanne = build_scene()
    render(out / "cage-mesh.png")

    cage, wire = make(suzanne)  # the defaults: the cage, then the mesh bound to it and posed
    render(out / "cage-made.png")
    api.bind(suzanne, cage, progress=lambda fraction, message: None)
    rest = np.array([vertex.co[:] for vertex in cage.data.vertices])
    set_vertices(cage.data, posed(rest))
    render(out / "cage-posed.png")
    set_vertices(cage.data, rest)
    api.unbind(suzanne)
    drop(wire, cage)

    for vertices in (30, 200):
        cage, wire = make(suzanne, vertices=vertices)
        render(out / f"cage-vertices-{vertices}.png")
        drop(wire, cage)
    cage, wire = make(suzanne, vertices=30, margin=0.05)  # beside the 30 vertices at the default margin
    render(out / "cage-margin-0.05.png")
    drop(wire, cage)

    # A partial cage around her right ear and the side of her head, bound with the modifier's Vertex Group: only that
    # part follows. (The ear alone, a thin flap, gives no cage: lbc_core refuses it at every margin.)
    ear = suzanne.vertex_groups.new(name="Ear")
    ear.add([vertex.index for vertex in suzanne.data.vertices if vertex.co.x > EAR_GROUP_X], 1.0, "REPLACE")
    cage, wire = make(suzanne, vertices=30, vertex_group="Ear")
    render(out / "cage-vertex-group.png")
    api.bind(suzanne, cage, progress=lambda fraction, message: None)
    api.set_deformer(suzanne, vertex_group="Ear")
    rest = np.array([vertex.co[:] for vertex in cage.data.vertices])
    lifted = posed(rest)
    lifted[:, 2] = np.where(rest[:, 2] > HEAD_TOP_Z, rest[:, 2], lifted[:, 2])  # the ear's cage: no head to pull
    set_vertices(cage.data, lifted)
    render(out / "cage-vertex-group-posed.png")


if __name__ == "__main__":
    main()
    # The bpy module of Blender 4.5 can hang at interpreter exit once an add-on is registered (see tests/conftest.py).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
