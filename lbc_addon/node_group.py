"""The deformer's node group: Geometry Nodes built from Python, which deform a bound mesh by its cached weights.

The node group reads the evaluated cage through Object Info in relative mode (so the cage's positions arrive in the
mesh's local space, following its animation, armature, drivers), samples the cage position of each of the K slots,
and moves every vertex by (Σ w_k c_k − rest) × Strength × its vertex group weight (see :mod:`storage`); the last
slots, which few vertices use, are evaluated on those vertices only (:func:`shared_slot_count`). Geometry
Nodes is compiled C++ evaluated in the depsgraph: it runs in renders, in the viewport while the cage is edited, and in
files opened without this add-on.

When the cage's vertex count differs from the one bound (or the cage is gone), the node group itself passes the mesh
through undeformed and shows an error on the modifier: that works without the add-on. A change of topology that keeps
the vertex count (faces rebuilt, vertices reordered) is caught by :func:`handlers.check_bindings`, which clears the
modifier's "Enabled" input (:mod:`deformer`); the panel says why and offers Rebind.
"""

import enum
import os
import tempfile

import bpy
import numpy as np

from . import storage
from .core import __version__ as core_version

GROUP_NAME = "LBC Deform"
# A node group's custom property recording what it was built for (see :func:`layout`), so that binding again with the
# same counts keeps it: building one takes 0.05-0.15 s, a fifth of a warm Rebind.
LAYOUT_KEY = "lbc_layout"
# The version of the node group's layout: bump it when build_node_group's nodes change, so older groups are rebuilt.
LAYOUT_VERSION = 2

_COLUMN = 220  # node editor spacing, for a readable node group
# Blender 4.3 and newer: the node group shows its reasons to stop as errors on the modifier.
HAS_WARNING_NODE = hasattr(bpy.types, "GeometryNodeWarning")
# What the modifier's errors begin with, so that the artist sees which modifier speaks.
WARNING_PREFIX = "LBC: "


class StopCause(enum.Enum):
    """Why the node group leaves the mesh undeformed; each has its Warning node, named ``"Stop: " + value``."""

    CAGE_VERTICES = "cage vertices"  # the cage is gone or has another vertex count
    MESH_VERTICES = "mesh vertices"  # the mesh reaching the modifier has another vertex count
    DISABLED = "disabled"  # the add-on cleared "Enabled": the cage's topology changed, its vertex count kept


def stop_messages(cage_vertex_count, mesh_vertex_count):
    """{StopCause: what to tell}, for the bind's counts: the Warning nodes show them (after :data:`WARNING_PREFIX`),
    and :mod:`diagnosis` tells them for the cause it looks up (:func:`warning_cause`)."""
    return {
        StopCause.CAGE_VERTICES: f"the cage is gone or no longer has the {cage_vertex_count} vertices it was bound "
                                 "with; the mesh is left undeformed. Bind again, or restore the cage",
        StopCause.MESH_VERTICES: f"the mesh reaching this modifier no longer has the {mesh_vertex_count} vertices it "
                                 "was bound with (edited, joined, separated, or a modifier above adds or removes "
                                 "vertices); it is left undeformed. Rebind in the LBC panel, or move the LBC modifier "
                                 "above any modifier that adds or removes vertices",
        StopCause.DISABLED: "the cage's topology changed since binding (same vertex count); the mesh is left "
                            "undeformed. Rebind in the LBC panel",
    }


def _warning_node_name(cause):
    return f"Stop: {cause.value}"


def warning_cause(group, message):
    """The :class:`StopCause` whose Warning node in ``group`` shows ``message`` (one of the modifier's
    ``node_warnings``), or None for a message no such node of the group shows."""
    causes = {_warning_node_name(cause): cause for cause in StopCause}
    for node in group.nodes:
        if node.bl_idname == "GeometryNodeWarning" and _input(node, "Message").default_value == message:
            return causes.get(node.name)
    return None

# The Strength input's range, as its slider offers it.
STRENGTH_RANGE = (-10.0, 10.0)

# The slots beyond those every vertex evaluates are left to at most this share of the vertices (see
# :func:`shared_slot_count`; bench/RESULTS.md: 5 % gave the fastest split on both benchmark scenes).
TAIL_SHARE = 0.05


def build_node_group(slots, cage_vertex_count, mesh_vertex_count, shared_slots=None):
    """A new node group deforming by ``slots`` (index, weight) attribute pairs.

    ``shared_slots``: None, every slot evaluated for every vertex; B < ``slots``, the first B for every vertex and
    the others only for the vertices with a nonzero weight in slot B (each vertex's padding comes last, see
    :func:`storage.slot_arrays`), a second Set Position on that selection. The counts at bind time are baked into its
    error messages; the modifier's inputs carry them for the checks.
    """
    group = bpy.data.node_groups.new(GROUP_NAME, "GeometryNodeTree")
    group.is_modifier = True
    _add_sockets(group.interface)
    nodes, links = group.nodes, group.links
    group_in = nodes.new("NodeGroupInput")
    group_out = nodes.new("NodeGroupOutput")

    cage = nodes.new("GeometryNodeObjectInfo")
    cage.transform_space = "RELATIVE"
    cage.location = (_COLUMN, 300)
    links.new(group_in.outputs["Cage"], _input(cage, "Object"))
    cage_geometry = cage.outputs["Geometry"]

    position = nodes.new("GeometryNodeInputPosition")
    position.location = (_COLUMN, -100)
    shared = slots if shared_slots is None else min(shared_slots, slots)
    total = pairwise_sum(group, _weighted_samples(group, cage_geometry, position, range(shared)), _COLUMN * 5)

    rest = _named_attribute(nodes, "FLOAT_VECTOR", storage.REST_NAME, (_COLUMN * 7.5, 300))
    displacement = _vector_math(nodes, "SUBTRACT", (_COLUMN * 8.5, 150))
    links.new(total, _inputs(displacement, "Vector")[0])
    links.new(rest.outputs["Attribute"], _inputs(displacement, "Vector")[1])
    factor, plain = _factor(group, group_in)
    set_position = nodes.new("GeometryNodeSetPosition")
    set_position.location = (_COLUMN * 9.5, 150)
    links.new(group_in.outputs["Geometry"], _input(set_position, "Geometry"))
    links.new(_scaled(group, displacement.outputs["Vector"], factor, plain), _input(set_position, "Offset"))
    deformed = set_position.outputs["Geometry"]
    if shared < slots:
        deformed = _add_tail(group, deformed, cage_geometry, position, range(shared, slots), factor, plain)

    stop = _stop_condition(group, group_in, cage_geometry, cage_vertex_count, mesh_vertex_count)
    switch = nodes.new("GeometryNodeSwitch")
    switch.input_type = "GEOMETRY"
    switch.location = (_COLUMN * 10.5, 400)
    links.new(stop, _input(switch, "Switch"))
    links.new(deformed, _input(switch, "False"))
    links.new(group_in.outputs["Geometry"], _input(switch, "True"))
    group_out.location = (_COLUMN * 11.5, 0)
    links.new(switch.outputs["Output"], _input(group_out, "Geometry"))
    return group


def _add_sockets(interface):
    """The group's inputs (the modifier's: Geometry, Cage, Strength, Vertex Group, Invert Vertex Group; hidden from
    it: the counts at bind time and Enabled) and its Geometry output."""
    interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    interface.new_socket("Cage", in_out="INPUT", socket_type="NodeSocketObject")
    strength = _single_value(interface.new_socket("Strength", in_out="INPUT", socket_type="NodeSocketFloat"))
    strength.default_value, (strength.min_value, strength.max_value) = 1.0, STRENGTH_RANGE
    strength.description = "How far the mesh follows the cage: 0 rest, 1 the full deformation"
    vertex_group = interface.new_socket("Vertex Group", in_out="INPUT", socket_type="NodeSocketString")
    vertex_group.description = "Only the vertices of this group follow the cage, by their weight (empty: all)"
    invert = interface.new_socket("Invert Vertex Group", in_out="INPUT", socket_type="NodeSocketBool")
    invert.description = "Vertices outside the group follow the cage instead"
    internal = (
        ("Cage Vertices", "NodeSocketInt", "Vertex count of the cage at bind time; any other count stops the deformer"),
        ("Mesh Vertices", "NodeSocketInt", "Vertex count of the mesh at bind time; any other count stops the deformer"),
        ("Enabled", "NodeSocketBool", "Cleared by the LBC add-on when the cage's topology changed since binding"),
    )
    for name, socket_type, description in internal:
        socket = interface.new_socket(name, in_out="INPUT", socket_type=socket_type)
        socket.description = description
        socket.hide_in_modifier = True
    interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")


def shared_slot_count(weight):
    """How many slots the deformer evaluates for every vertex: the fewest B after which at most :data:`TAIL_SHARE`
    of the vertices have weights left, the others evaluated on those vertices only.

    Parameters
    ----------
    weight : (m, K) array
        The stored slots' weights, each vertex's padding last (:func:`storage.slot_arrays`).

    Returns
    -------
    int
        B in 1 … K; K (no tail) when no B qualifies, or where a vertex has a weight after an empty slot B, which the
        tail's selection (slot B's weight nonzero) would miss.
    """
    used = weight != 0
    share = used.sum(axis=0) / max(len(weight), 1)
    for shared in range(1, weight.shape[1]):
        if share[shared] <= TAIL_SHARE and np.array_equal(used[:, shared:].any(axis=1), used[:, shared]):
            return shared
    return weight.shape[1]


def pairwise_sum(group, terms, x):
    """The sum of the vector outputs ``terms`` as a balanced tree of Add nodes, its first column at ``x``.

    Against a chain of Adds (bench/RESULTS.md): 5-7 % faster at the default K of 12 in the one run comparing them
    there, within the noise at larger K.
    """
    while len(terms) > 1:
        pairs = []
        for first, second in zip(terms[::2], terms[1::2]):
            add = _vector_math(group.nodes, "ADD", (x, first.node.location.y))
            group.links.new(first, _inputs(add, "Vector")[0])
            group.links.new(second, _inputs(add, "Vector")[1])
            pairs.append(add.outputs["Vector"])
        terms = pairs + terms[len(terms) - len(terms) % 2:]
        x += _COLUMN / 2
    return terms[0]


def _weighted_samples(group, cage_geometry, position, slots):
    """Per slot of ``slots`` the vector output w_k c_k: the cage position at the slot's index times its weight."""
    nodes, links = group.nodes, group.links
    terms = []
    for slot in slots:
        y = -200 - 260 * slot
        index = _named_attribute(nodes, "INT", storage.index_name(slot), (_COLUMN * 2, y))
        weight = _named_attribute(nodes, "FLOAT", storage.weight_name(slot), (_COLUMN * 2, y - 120))
        sample = nodes.new("GeometryNodeSampleIndex")
        sample.data_type = "FLOAT_VECTOR"
        sample.domain = "POINT"
        sample.location = (_COLUMN * 3, y)
        links.new(cage_geometry, _input(sample, "Geometry"))
        links.new(position.outputs["Position"], _input(sample, "Value"))
        links.new(index.outputs["Attribute"], _input(sample, "Index"))
        scaled = _vector_math(nodes, "SCALE", (_COLUMN * 4, y))
        links.new(sample.outputs["Value"], _input(scaled, "Vector"))
        links.new(weight.outputs["Attribute"], _input(scaled, "Scale"))
        terms.append(scaled.outputs["Vector"])
    return terms


def _add_tail(group, geometry, cage_geometry, position, slots, factor, plain):
    """``geometry`` moved further by Σ w_k c_k over ``slots`` (× the factor), on the vertices that use the first of
    them: a Set Position evaluates its fields on its selection only, so the tail costs what its few vertices need."""
    nodes, links = group.nodes, group.links
    first = slots[0]
    tail = pairwise_sum(group, _weighted_samples(group, cage_geometry, position, slots), _COLUMN * 5)
    weight = _named_attribute(nodes, "FLOAT", storage.weight_name(first), (_COLUMN * 7.5, -300 - 260 * first))
    used = _compare(nodes, "FLOAT", "NOT_EQUAL", (_COLUMN * 8.5, -300 - 260 * first))
    links.new(weight.outputs["Attribute"], _input(used, "A"))
    _input(used, "B").default_value = 0.0
    _input(used, "Epsilon").default_value = 0.0
    set_tail = nodes.new("GeometryNodeSetPosition")
    set_tail.location = (_COLUMN * 10, -300 - 260 * first)
    links.new(geometry, _input(set_tail, "Geometry"))
    links.new(used.outputs["Result"], _input(set_tail, "Selection"))
    links.new(_scaled(group, tail, factor, plain), _input(set_tail, "Offset"))
    return set_tail.outputs["Geometry"]


def _factor(group, group_in):
    """The Strength × the vertex group's weight (inverted on request), and whether it is 1 everywhere: outputs
    (factor, plain) for :func:`_scaled`.

    Like Mesh Deform's, a vertex group name that names no attribute of the mesh (or none) masks nothing. ``plain``
    (Strength 1 and no vertex group) is a single value, never a field.
    """
    nodes, links = group.nodes, group.links
    length = nodes.new("FunctionNodeStringLength")
    length.location = (_COLUMN * 3, 1100)
    links.new(group_in.outputs["Vertex Group"], _input(length, "String"))
    has_group = _compare(nodes, "INT", "GREATER_THAN", (_COLUMN * 4, 1100))
    links.new(length.outputs["Length"], _input(has_group, "A"))
    _input(has_group, "B").default_value = 0
    grouped = has_group.outputs["Result"]

    weight = nodes.new("GeometryNodeInputNamedAttribute")
    weight.data_type = "FLOAT"
    weight.location = (_COLUMN * 4, 900)
    links.new(group_in.outputs["Vertex Group"], _input(weight, "Name"))
    complement = _math(nodes, "SUBTRACT", (_COLUMN * 5, 950))
    _inputs(complement, "Value")[0].default_value = 1.0
    links.new(weight.outputs["Attribute"], _inputs(complement, "Value")[1])
    inverted = _switch(nodes, "FLOAT", (_COLUMN * 5.5, 900))
    links.new(group_in.outputs["Invert Vertex Group"], _input(inverted, "Switch"))
    links.new(weight.outputs["Attribute"], _input(inverted, "False"))
    links.new(complement.outputs["Value"], _input(inverted, "True"))
    mask = _switch(nodes, "FLOAT", (_COLUMN * 6, 900))
    links.new(weight.outputs["Exists"], _input(mask, "Switch"))
    _input(mask, "False").default_value = 1.0
    links.new(inverted.outputs["Output"], _input(mask, "True"))
    masked = _math(nodes, "MULTIPLY", (_COLUMN * 6.5, 900))
    links.new(mask.outputs["Output"], _inputs(masked, "Value")[0])
    links.new(group_in.outputs["Strength"], _inputs(masked, "Value")[1])
    factor = _switch(nodes, "FLOAT", (_COLUMN * 7, 800))
    links.new(grouped, _input(factor, "Switch"))
    links.new(group_in.outputs["Strength"], _input(factor, "False"))
    links.new(masked.outputs["Value"], _input(factor, "True"))

    full = _compare(nodes, "FLOAT", "EQUAL", (_COLUMN * 4, 1250))
    links.new(group_in.outputs["Strength"], _input(full, "A"))
    _input(full, "B").default_value = 1.0
    _input(full, "Epsilon").default_value = 0.0
    plain = nodes.new("FunctionNodeBooleanMath")
    plain.operation = "NIMPLY"  # Strength 1 and no vertex group
    plain.location = (_COLUMN * 5, 1200)
    links.new(full.outputs["Result"], _inputs(plain, "Boolean")[0])
    links.new(grouped, _inputs(plain, "Boolean")[1])
    return factor.outputs["Output"], plain.outputs["Boolean"]


def _scaled(group, vector, factor, plain):
    """The vector output ``vector`` × ``factor`` (see :func:`_factor`), or ``vector`` itself where ``plain``.

    Per vertex only what is needed is computed: a Switch whose condition is a single value evaluates only the input
    it passes on, so with no vertex group and Strength 1 the vector goes through as it is (the mask and the product
    cost 12 % of the deformer's time on the Suzanne scene of bench/blender_deform.py).
    """
    nodes, links = group.nodes, group.links
    location = vector.node.location
    scaled = _vector_math(nodes, "SCALE", (location.x + _COLUMN, location.y + 200))
    links.new(vector, _input(scaled, "Vector"))
    links.new(factor, _input(scaled, "Scale"))
    chosen = _switch(nodes, "VECTOR", (location.x + _COLUMN * 1.5, location.y))
    links.new(plain, _input(chosen, "Switch"))
    links.new(scaled.outputs["Vector"], _input(chosen, "False"))
    links.new(vector, _input(chosen, "True"))
    return chosen.outputs["Output"]


def _math(nodes, operation, location):
    node = nodes.new("ShaderNodeMath")
    node.operation = operation
    node.location = location
    return node


def _compare(nodes, data_type, operation, location):
    node = nodes.new("FunctionNodeCompare")
    node.data_type = data_type
    node.operation = operation
    node.location = location
    return node


def _switch(nodes, input_type, location):
    node = nodes.new("GeometryNodeSwitch")
    node.input_type = input_type
    node.location = location
    return node


def _single_value(socket):
    """Make a group input a single value, never a field (no attribute toggle on the modifier): what the Switch
    nodes of :func:`_scaled` need to evaluate one input only. 4.5 and newer say it with ``structure_type``."""
    if hasattr(socket, "structure_type"):
        socket.structure_type = "SINGLE"
    else:
        socket.force_non_field = True
    return socket


def _named_attribute(nodes, data_type, name, location):
    node = nodes.new("GeometryNodeInputNamedAttribute")
    node.data_type = data_type
    _input(node, "Name").default_value = name
    node.location = location
    return node


def _inputs(node, name):
    """The node's enabled input sockets called ``name``, in order.

    Sockets are found by name among those the node's current type enables, never by position: Blender versions
    differ in how many hidden sockets a node carries (5.2's integer Compare has two inputs, 4.x's thirteen).
    """
    found = [socket for socket in node.inputs if socket.name == name and socket.enabled]
    if not found:
        raise KeyError(f"{node.bl_idname} has no enabled input {name!r}")
    return found


def _input(node, name):
    """The node's first enabled input socket called ``name``."""
    return _inputs(node, name)[0]


def _vector_math(nodes, operation, location):
    node = nodes.new("ShaderNodeVectorMath")
    node.operation = operation
    node.location = location
    return node


def _stop_condition(group, group_in, cage_geometry, cage_vertex_count, mesh_vertex_count):
    """The boolean output that is true when the mesh must stay undeformed.

    Three causes, each with its own modifier error where Blender has the Warning node (4.3 and newer): the cage is
    gone or has another vertex count, the mesh has another vertex count, the add-on cleared "Enabled" (the cage's
    topology changed with its vertex count kept).
    """
    nodes, links = group.nodes, group.links
    cage_changed = _count_differs(group, cage_geometry, group_in.outputs["Cage Vertices"], (_COLUMN * 2, 500))
    mesh_changed = _count_differs(group, group_in.outputs["Geometry"], group_in.outputs["Mesh Vertices"],
                                  (_COLUMN * 2, 800))
    disabled = nodes.new("FunctionNodeBooleanMath")
    disabled.operation = "NOT"
    disabled.location = (_COLUMN * 3, 650)
    links.new(group_in.outputs["Enabled"], _inputs(disabled, "Boolean")[0])
    messages = stop_messages(cage_vertex_count, mesh_vertex_count)
    causes = ((cage_changed, StopCause.CAGE_VERTICES), (mesh_changed, StopCause.MESH_VERTICES),
              (disabled.outputs["Boolean"], StopCause.DISABLED))
    # The raw conditions stop the deformer too, not only through the Warning nodes: Blender 4.2 loads those as
    # undefined nodes whose outputs are false, and a group made in 4.3 or newer then never stopped there.
    stops = []
    for row, (condition, cause) in enumerate(causes):
        shown = _warning(nodes, links, condition, cause, messages[cause], (_COLUMN * 4, 500 + 150 * row))
        stops += [condition] if shown is condition else [condition, shown]
    stop = stops[0]
    for row, condition in enumerate(stops[1:]):
        either = nodes.new("FunctionNodeBooleanMath")
        either.operation = "OR"
        either.location = (_COLUMN * 5, 550 + 100 * row)
        links.new(stop, _inputs(either, "Boolean")[0])
        links.new(condition, _inputs(either, "Boolean")[1])
        stop = either.outputs["Boolean"]
    return stop


def _count_differs(group, geometry, expected, location):
    """Boolean output: the geometry's mesh vertex count differs from the integer ``expected``."""
    nodes, links = group.nodes, group.links
    size = nodes.new("GeometryNodeAttributeDomainSize")
    size.component = "MESH"
    size.location = location
    links.new(geometry, _input(size, "Geometry"))
    differs = _compare(nodes, "INT", "NOT_EQUAL", (location[0] + _COLUMN, location[1]))
    links.new(size.outputs["Point Count"], _input(differs, "A"))
    links.new(expected, _input(differs, "B"))
    return differs.outputs["Result"]


def _warning(nodes, links, condition, cause, message, location):
    """``condition`` passed through a Warning node, named after ``cause``, that shows ``message`` on the modifier
    while it is true; the condition itself where Blender has no Warning node (4.2)."""
    if not HAS_WARNING_NODE:
        return condition
    node = nodes.new("GeometryNodeWarning")
    node.name = _warning_node_name(cause)
    node.warning_type = "ERROR"
    _input(node, "Message").default_value = WARNING_PREFIX + message
    node.location = location
    links.new(condition, _input(node, "Show"))
    return node.outputs["Show"]


def layout(slots, cage_vertex_count, mesh_vertex_count, shared_slots):
    """What a node group is built for, as its :data:`LAYOUT_KEY` property stores it: the counts, the add-on's version
    and :data:`LAYOUT_VERSION` (a group of another layout is built again), and whether it has Warning nodes. Groups
    made before LAYOUT_VERSION carried a digest of the add-on's source in its place: they differ, so are rebuilt."""
    shared = slots if shared_slots is None else min(shared_slots, slots)
    return (f"{core_version} layout {LAYOUT_VERSION} slots {slots} shared {shared} cage {cage_vertex_count} "
            f"mesh {mesh_vertex_count} warnings {int(HAS_WARNING_NODE)}")


def has_warning_nodes(group):
    """Whether the node group has Warning nodes (made where Blender has them: 4.3 and newer)."""
    return any(node.bl_idname == "GeometryNodeWarning" for node in group.nodes)


def outdated(group):
    """Whether a node group of this add-on does not suit the running Blender: nodes it does not know (a group made in a
    newer line, opened in 4.2), or where Blender has Warning nodes, not one named after each :class:`StopCause`
    (made in 4.2, or before they were named), whose errors the modifier and the panel's diagnosis rely on."""
    named = {node.name for node in group.nodes if node.bl_idname == "GeometryNodeWarning"}
    return (any(node.bl_idname == "NodeUndefined" for node in group.nodes)
            or (HAS_WARNING_NODE and named != {_warning_node_name(cause) for cause in StopCause}))


def saved_bytes(group):
    """What ``group`` adds to a saved .blend, in bytes: the size of a file holding it alone (written with
    ``bpy.data.libraries.write``, uncompressed as Blender saves by default) less that of an empty one. The group is
    about 3.7 kB a node in 4.5, as much as the weights on a mesh of a few thousand vertices (bench/RESULTS.md, "What a
    binding adds to the .blend")."""
    with tempfile.TemporaryDirectory() as folder:
        empty, alone = os.path.join(folder, "empty.blend"), os.path.join(folder, "group.blend")
        bpy.data.libraries.write(empty, set(), compress=False)
        bpy.data.libraries.write(alone, {group}, compress=False)
        return max(os.path.getsize(alone) - os.path.getsize(empty), 0)
