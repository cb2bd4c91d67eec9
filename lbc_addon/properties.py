"""What the add-on remembers per object (``Object.lbc``): the binding's cage, options, figures and state.

Stored as ID properties, so it is saved in the .blend; Unbind removes the whole group again.
"""

import bpy
from bpy.app.handlers import persistent
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty, PointerProperty,
                       StringProperty)

from .core import DEFAULT_CELLS, DEFAULT_SMOOTHNESS, DEFAULT_TOLERANCE, floor_for
from .options import DEFAULT_INFLUENCES, AddonOptions

# lbc_core's weighting functions ρ of the geodesic distance D in the TV weights ω = ρ(D).
WEIGHTING_ITEMS = (
    ("quadratic", "Quadratic", "ρ(D) = D², the paper's choice: the most local coordinates"),
    ("linear", "Linear", "ρ(D) = D"),
    ("sqrt", "Square Root", "ρ(D) = √D: smoother, less local"),
    ("constant", "Constant", "ρ(D) = 1: plain total variation, no locality prior"),
)

# lbc_core's meshers of 3D cages that the extension bundles (lbc_core.meshing.MESHERS), "auto" first.
MESHER_ITEMS = (
    ("auto", "Auto", "lbc_core's default mesher, the same in every Blender and on the command line (lbc bind)"),
    ("delaunay", "Delaunay", "A conforming Delaunay tetrahedralisation of samples on the cage and a body-centred "
     "cubic lattice inside"),
)

MODE_ITEMS = (
    ("AUTO", "Automatic", "2D when the cage and the mesh lie flat in one plane (image planes, flat meshes), else 3D"),
    ("3D", "3D", "A closed cage around the mesh"),
    ("2D", "2D", "A flat cage: its outline is the 2D polygon; the mesh must lie in its plane"),
)


# Whether the deformer works: the panel picks its icon and actions from this, and shows ``status`` (the why) as text.
# Numbered, because files store the number: UNBOUND came last, so the states saved before it keep theirs.
STATE_ITEMS = (
    ("FOLLOWING", "Following", "The mesh follows its cage", 0),
    ("STOPPED", "Stopped", "The deformer cannot work (the status says why): the mesh stays at rest", 1),
    ("UNBOUND", "Unbound", "The mesh is not bound to a cage", 2),
)


class BindOptionProperties:
    """The bind options shared by the operators' properties and the stored binding (annotations only), in the order
    the Bind operator shows them."""

    mode: EnumProperty(name="Dimension", items=MODE_ITEMS, default="AUTO")
    smoothness: FloatProperty(
        name="Smoothness",
        description="Smooth joints or local weights. Higher: bent joints (elbows, fingers, a twisted limb) fold and "
        "crease less, each vertex follows more cage vertices (a slower deformer, and a cage vertex moves more of the "
        "mesh around it). Lower: each vertex follows the fewest cage vertices, the most local. "
        f"{DEFAULT_SMOOTHNESS:g} folds a character's joints less than Mesh Deform (docs/blender.md)",
        default=DEFAULT_SMOOTHNESS,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
    )
    cells: IntProperty(
        name="Cells",
        description=f"About how many cells (triangles in 2D, tetrahedra in 3D) fill the cage; 0 uses lbc's default "
        f"({DEFAULT_CELLS[2]} in 2D, {DEFAULT_CELLS[3]} in 3D). More cells: finer weights, slower bind",
        default=0,
        min=0,
        soft_max=200000,
    )
    mesher: EnumProperty(name="Mesher", description="What fills a 3D cage with tetrahedra before the solve (a flat "
                         "cage bound in 2D uses lbc_core's default)", items=MESHER_ITEMS, default="auto")
    weighting: EnumProperty(name="Weighting", description="How the geodesic distance weighs the total variation",
                            items=WEIGHTING_ITEMS, default="quadratic")
    epsilon: FloatProperty(
        name="Relaxation ε",
        description="C¹ relaxation of the total variation: the gradient's length is smoothed below ε (on a cage "
        "scaled to unit size). 0: the paper's plain LBC; 0.01: a little smoother; 0.1: smoother weights that reach "
        "much further; 1 and more: close to harmonic coordinates, far less local",
        default=0.0,
        min=0.0,
        soft_max=10.0,
        precision=4,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description="Stopping tolerance of the solver (relative ADMM residual); 0 uses lbc's default "
        f"({DEFAULT_TOLERANCE[2]:g} in 2D, {DEFAULT_TOLERANCE[3]:g} in 3D, tighter for cages of a few vertices). "
        "Smaller: more accurate weights, slower bind",
        default=0.0,
        min=0.0,
        soft_max=0.01,
        precision=6,
    )
    thinning: FloatProperty(
        name="Thinning",
        description="Every weight is lowered by this and those that reach 0 are dropped; the others are then made "
        f"to sum to 1 and reproduce the vertex again, so weights fade in and out without creases. 0 follows "
        f"Smoothness ({floor_for(0.0):g} at 0, {floor_for(1.0):g} at 1; 1e-9 keeps every weight). Larger: fewer "
        "influences per vertex, a faster deformer, a "
        "less smooth deformation. It never takes more than a tenth of a vertex's weight, so where weights spread over "
        "most of a small cage (Blender's Cylinder) it removes none: Max Influences does",
        default=0.0,
        min=0.0,
        soft_max=0.05,
        precision=5,
    )
    influences: IntProperty(
        name="Max Influences",
        description="At most this many cage vertices move one mesh vertex (the weights are lowered by each vertex's "
        "next largest one, then made to sum to 1 and reproduce the vertex again; a vertex that needs more to stay in "
        "place keeps the fewest that can); the deformer's cost per frame grows with it. 0: no limit (the default; a "
        "cap makes the deformer faster but can crease a bent smooth mesh)",
        default=DEFAULT_INFLUENCES,
        min=0,
        soft_max=32,
    )

    def bind_options(self):
        """The options, as :class:`~lbc_addon.options.AddonOptions` (checked)."""
        return AddonOptions.read(self)


OPTION_NAMES = tuple(BindOptionProperties.__annotations__)


class LBC_PG_binding(BindOptionProperties, bpy.types.PropertyGroup):
    """A mesh object's binding to a cage."""

    is_bound: BoolProperty(name="Bound", default=False)
    cage: PointerProperty(name="Cage", type=bpy.types.Object,
                          description="The cage this mesh is bound to")
    node_group: PointerProperty(type=bpy.types.NodeTree)
    dimension: IntProperty(name="Dimension", description="2 or 3: how the weights were computed")
    cage_vertex_count: IntProperty(name="Cage Vertices")
    mesh_vertex_count: IntProperty(name="Mesh Vertices", description="The mesh's vertex count at bind time")
    cage_topology: StringProperty(name="Cage Topology", description="Fingerprint of the cage's topology at bind time")
    bind_report: StringProperty(name="Bind Report", description="How the last bind went when it started from a "
                                "previous binding: what was solved again, or why it bound from scratch")
    cage_shape: StringProperty(name="Cage Shape", description="Fingerprint of the cage's own vertex positions (before "
                               "modifiers) at bind time: an edit at rest changes it, a pose does not")
    mesh_transform: FloatVectorProperty(name="Mesh Transform", size=16, description="The mesh object's own transform "
                                        "(location, rotation, scale) at bind time, row by row (all 0: not recorded)")
    mesh_in_cage: FloatVectorProperty(name="Mesh in Cage", size=16, description="The mesh object's world transform in "
                                      "its cage's frame at bind time, row by row (all 0: not recorded)")
    core_fingerprint: StringProperty(name="Core Fingerprint", description="lbc_core's fingerprint of the welded cage")
    welded: StringProperty(name="Welded", description="Cage vertices that were one point at bind time, as copy:kept "
                           "pairs: the deformer reads the kept one, so the copies must stay with it")
    control_points: IntProperty(name="Control Points", description="Cage vertices after welding duplicates")
    domain_cells: IntProperty(name="Cells Made", description="The triangles or tetrahedra the weights were computed "
                              "on (0: not recorded)")
    node_group_bytes: IntProperty(name="Node Group Size", description="What the deformer's node group adds to a saved "
                                  ".blend, in bytes, measured at bind time (0: not measured)")
    slots: IntProperty(name="Slots", description="K: the largest number of cage vertices moving one mesh vertex")
    mean_influences: FloatProperty(name="Mean Influences")
    outside: IntProperty(name="Outside", description="Mesh vertices outside the cage at bind time")
    bind_seconds: FloatProperty(name="Bind Time", unit="TIME_ABSOLUTE")
    warnings: StringProperty(name="Warnings", description="What lbc_core repaired or noticed at bind time")
    state: EnumProperty(name="State", items=STATE_ITEMS, default="UNBOUND")
    status: StringProperty(name="Status", description="Why the deformer works or stopped")
    active_modifier: StringProperty(description="The modifier that was active before binding, made active again on "
                                    "unbind")
    show_influence: BoolProperty(name="Show Influence", default=False)
    influence_vertex: IntProperty(name="Influence Vertex", description="The cage vertex whose weights are shown")
    previous_color: StringProperty(description="The active color attribute before showing the influence")
    previous_color_type: StringProperty(
        description="The 3D views switched to attribute colors by showing the influence, and their Solid color type "
        'before: "screen|area index|color type;..."'
    )


def is_bound(obj):
    """Whether ``obj`` holds a binding.

    Reading ``obj.lbc`` creates the property group on the object (Blender 4.x), so checks that look at every object
    ask ``is_property_set`` first: objects never bound stay exactly as they are. Registered properties are read as
    attributes, never as ID properties (``obj.get``), which Blender 5.0 keeps apart from them.
    """
    return obj.type == "MESH" and obj.is_property_set("lbc") and obj.lbc.is_bound


def bound_to(cage, objects):
    """The objects among ``objects`` bound to ``cage``."""
    return [obj for obj in objects if is_bound(obj) and obj.lbc.cage == cage]


# Options stored under another name by earlier versions of the add-on: (old name, property).
RENAMED_OPTIONS = (("resolution", "cells"),)


@persistent
def adopt_renamed_options(*_args):
    """Move the values a file saved by an earlier version keeps under an option's old name onto the current one, so
    a Rebind uses the cell count the artist chose (the old key stays readable as an ID property in 4.2-5.2)."""
    for obj in bpy.data.objects:
        if not is_bound(obj):
            continue
        for old, new in RENAMED_OPTIONS:
            value = obj.lbc.get(old)
            if value is not None:
                setattr(obj.lbc, new, value)
                del obj.lbc[old]


def register():
    bpy.utils.register_class(LBC_PG_binding)
    bpy.types.Object.lbc = PointerProperty(type=LBC_PG_binding)
    bpy.app.handlers.load_post.append(adopt_renamed_options)


def unregister():
    if adopt_renamed_options in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(adopt_renamed_options)
    del bpy.types.Object.lbc
    bpy.utils.unregister_class(LBC_PG_binding)
