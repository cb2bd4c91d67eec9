"""The live deformer: a Geometry Nodes modifier built from Python, and the checks that keep it honest.

The node group reads the evaluated cage through Object Info in relative mode (so the cage's positions arrive in the
mesh's local space, following its animation, armature, drivers), samples the cage position of each of the K slots,
and moves every vertex by (Σ w_k c_k − rest) × Strength × its vertex group weight (see :mod:`storage`); the last
slots, which few vertices use, are evaluated on those vertices only (:func:`shared_slot_count`). Geometry
Nodes is compiled C++ evaluated in the depsgraph: it runs in renders, in the viewport while the cage is edited, and in
files opened without this add-on.

When the cage's vertex count differs from the one bound (or the cage is gone), the node group itself passes the mesh
through undeformed and shows an error on the modifier: that works without the add-on. A change of topology that keeps
the vertex count (faces rebuilt, vertices reordered) is caught by :func:`check_bindings`, which clears the
modifier's "Enabled" input; the panel says why and offers Rebind.
"""

import functools
import hashlib
from pathlib import Path

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import geometry, storage
from .core import POSED_APART, lbc_core
from .jobs import read_welded
from .properties import bound_to, is_bound

MODIFIER_NAME = "LBC Deform"
GROUP_NAME = "LBC Deform"
# A node group's custom property recording what it was built for (see :func:`attach`), so that binding again with the
# same counts keeps it: building one takes 0.05-0.15 s, a fifth of a warm Rebind.
LAYOUT_KEY = "lbc_layout"
# This module's own text, digested: any change to it (how groups are built included) makes older groups be rebuilt.
_DESIGN = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]

_COLUMN = 220  # node editor spacing, for a readable node group
# Blender 4.3 and newer: the node group shows its reasons to stop as errors on the modifier.
HAS_WARNING_NODE = hasattr(bpy.types, "GeometryNodeWarning")

# Causes (see :func:`diagnose`) the node group cannot see, so the add-on clears its "Enabled" input.
STOPPED_HERE = ("topology", "welded apart", "rest moved")
# Causes that are the artist's own choice, not a fault: the panel says them, the console does not, and the binding
# still gives its deformation (Save as Shape Key saves it).
ARTISTS_CHOICE = ("modifier off",)

# The modifier inputs that are the artist's (kept when the mesh is bound again); the others are the add-on's.
USER_INPUTS = ("Strength", "Vertex Group", "Invert Vertex Group")
# The Strength input's range, as its slider offers it.
STRENGTH_RANGE = (-10.0, 10.0)

# The slots beyond those every vertex evaluates are left to at most this share of the vertices (see
# :func:`shared_slot_count`; bench/RESULTS.md: 5 % gave the fastest split on both benchmark scenes).
TAIL_SHARE = 0.05
# Vertices :func:`rest_moved` compares with their rest positions, spread over the mesh's order; and the rounding it
# allows, relative to the positions' magnitude: a few float32 ulps (the mesh's and its rest attribute's positions are
# float32, and the affine fit adds a little).
REST_SAMPLES = 16
FLOAT32_ROUNDING = 8 * float(np.finfo(np.float32).eps)
# And the share of the largest change the affine fit may leave unexplained: a move as a whole leaves only rounding; a
# stroke that pushed a few sampled vertices leaves most of their change (three quarters for one vertex of 16), even
# where it is within the rounding allowed far from the origin (a 0.01 stroke at x = 10⁴, a new user's finding).
UNEXPLAINED_SHARE = 0.1


def build_node_group(slots, cage_vertex_count, mesh_vertex_count, shared_slots=None):
    """A new node group deforming by ``slots`` (index, weight) attribute pairs.

    ``shared_slots``: None, every slot evaluated for every vertex; B < ``slots``, the first B for every vertex and
    the others only for the vertices with a nonzero weight in slot B (each vertex's padding comes last, see
    :func:`storage.slot_arrays`), a second Set Position on that selection. The counts at bind time are baked into its
    error messages; the modifier's inputs carry them for the checks.
    """
    group = bpy.data.node_groups.new(GROUP_NAME, "GeometryNodeTree")
    group.is_modifier = True
    interface = group.interface
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
    causes = (
        (cage_changed, f"LBC: the cage is gone or no longer has the {cage_vertex_count} vertices it was bound with; "
                       "the mesh is left undeformed. Bind again, or restore the cage"),
        (mesh_changed, f"LBC: the mesh reaching this modifier no longer has the {mesh_vertex_count} vertices it was "
                       "bound with (edited, joined, separated, or a modifier above adds or removes vertices); it is "
                       "left undeformed. Rebind in the LBC panel, or move the LBC modifier above any modifier that "
                       "adds or removes vertices"),
        (disabled.outputs["Boolean"], "LBC: the cage's topology changed since binding (same vertex count); the mesh "
                                      "is left undeformed. Rebind in the LBC panel"),
    )
    # The raw conditions stop the deformer too, not only through the Warning nodes: Blender 4.2 loads those as
    # undefined nodes whose outputs are false, and a group made in 4.3 or newer then never stopped there.
    stops = []
    for row, (condition, message) in enumerate(causes):
        shown = _warning(nodes, links, condition, message, (_COLUMN * 4, 500 + 150 * row))
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


def _warning(nodes, links, condition, message, location):
    """``condition`` passed through a Warning node that shows ``message`` on the modifier while it is true; the
    condition itself where Blender has no Warning node (4.2)."""
    if not HAS_WARNING_NODE:
        return condition
    node = nodes.new("GeometryNodeWarning")
    node.warning_type = "ERROR"
    _input(node, "Message").default_value = message
    node.location = location
    links.new(condition, _input(node, "Show"))
    return node.outputs["Show"]


def attach(mesh_obj, cage_obj, slots, cage_vertex_count, mesh_vertex_count, shared_slots=None):
    """Give ``mesh_obj`` the deformer for a new binding.

    A bound object keeps its LBC modifier (its place in the stack, name, Strength, vertex group) with a new node
    group; otherwise a new modifier goes first in the stack (the weights belong to the mesh's own vertices, before
    any other modifier moves them).

    ``shared_slots``: how many of the ``slots`` stored on the mesh every vertex evaluates (see
    :func:`build_node_group`; :func:`shared_slot_count` of the weights written, for a bind); None, every slot.

    The modifier's node group is kept when this build of the add-on made it for the same counts.

    Returns
    -------
    (modifier, replaced node group or None)
        The replaced group is still in the file: :func:`release_group` removes it once the binding is complete.
    """
    layout = _layout(slots, cage_vertex_count, mesh_vertex_count, shared_slots)
    modifier = find_modifier(mesh_obj)
    if modifier is None:
        modifier = mesh_obj.modifiers.new(MODIFIER_NAME, "NODES")
        mesh_obj.modifiers.move(len(mesh_obj.modifiers) - 1, 0)
    replaced, kept = modifier.node_group, inputs(modifier)
    if replaced is not None and replaced.get(LAYOUT_KEY) == layout and not outdated(replaced):
        replaced = None  # made for the same counts by this build in this Blender line: kept as it is
    else:
        modifier.node_group = build_node_group(slots, cage_vertex_count, mesh_vertex_count, shared_slots)
        modifier.node_group[LAYOUT_KEY] = layout
    group = modifier.node_group
    # Every input is set: a value Blender kept from the replaced group under the same identifier may be another one's.
    defaults = {item.name: item.default_value for item in _input_items(group) if item.socket_type != "NodeSocketObject"}
    set_inputs(modifier, {**defaults, **{name: kept[name] for name in USER_INPUTS if name in kept}, "Cage": cage_obj,
                          "Cage Vertices": cage_vertex_count, "Mesh Vertices": mesh_vertex_count, "Enabled": True})
    return modifier, replaced


def _layout(slots, cage_vertex_count, mesh_vertex_count, shared_slots):
    """What a node group is built for, as its :data:`LAYOUT_KEY` property stores it: the counts, the add-on's version
    and this module's digest (another build may make its groups otherwise), and whether it has Warning nodes."""
    shared = slots if shared_slots is None else min(shared_slots, slots)
    return (f"{lbc_core.__version__} {_DESIGN} slots {slots} shared {shared} cage {cage_vertex_count} "
            f"mesh {mesh_vertex_count} warnings {int(HAS_WARNING_NODE)}")


def _has_warning_nodes(group):
    return any(node.bl_idname == "GeometryNodeWarning" for node in group.nodes)


def outdated(group):
    """Whether a node group of this add-on does not suit the running Blender: nodes it does not know (a group made in a
    newer line, opened in 4.2), or no Warning nodes where Blender has them (made in 4.2), whose errors the modifier
    and the panel's diagnosis rely on."""
    return (any(node.bl_idname == "NodeUndefined" for node in group.nodes)
            or (HAS_WARNING_NODE and not _has_warning_nodes(group)))


def inputs(modifier):
    """The values of the modifier's inputs, by input name: {name: value}."""
    if modifier.node_group is None:
        return {}
    values = raw_inputs(modifier)
    return {item.name: values[item.identifier] for item in _input_items(modifier.node_group)
            if item.identifier in values}


def set_inputs(modifier, values):
    """Set the modifier's inputs by name; names its node group does not have are left out."""
    identifiers = {item.name: item.identifier for item in _input_items(modifier.node_group)}
    set_raw_inputs(modifier, {identifiers[name]: value for name, value in values.items() if name in identifiers})


def raw_inputs(modifier):
    """The values of the modifier's inputs by socket identifier, as stored: {identifier: value}."""
    stored = getattr(modifier, "properties", None)
    if stored is None:
        return {key: modifier[key] for key in modifier.keys()}
    return {item.identifier: getattr(stored.inputs, item.identifier).value for item in _input_items(modifier.node_group)
            if hasattr(stored.inputs, item.identifier)}


def set_raw_inputs(modifier, values):
    """Set the modifier's inputs by socket identifier (what :func:`raw_inputs` returned)."""
    for identifier, value in values.items():
        data, name = input_property(modifier, identifier)
        if name.startswith("["):
            data[identifier] = value
        else:
            setattr(data, name, value)


def input_property(modifier, identifier):
    """Where the modifier stores an input, as (data, property) for ``UILayout.prop`` and ``getattr``.

    Up to Blender 5.1 the inputs are ID properties of the modifier (``modifier["Socket_2"]``); from 5.2 they are
    registered properties (``modifier.properties.inputs.Socket_2.value``) and the modifier holds no ID properties.
    """
    stored = getattr(modifier, "properties", None)
    if stored is None:
        return modifier, f'["{identifier}"]'
    return getattr(stored.inputs, identifier), "value"


def input_identifier(modifier, name):
    """The socket identifier of the modifier's input called ``name``, or None when its node group has none.

    Found by Blender's own lookup by name (the first item so called; only the geometry's name is an input's and an
    output's): 0.001 ms against 0.03 for listing the items from Python, and the depsgraph handler asks after every
    cage edit.
    """
    item = modifier.node_group.interface.items_tree.get(name)
    return item.identifier if item is not None and _is_input(item) else None


def is_enabled(modifier):
    """Whether the modifier's "Enabled" input is on (True when its node group has none). Read alone, as the
    depsgraph handler does after every cage edit: :func:`inputs` reads every input."""
    identifier = input_identifier(modifier, "Enabled") if modifier.node_group is not None else None
    if identifier is None:
        return True
    data, name = input_property(modifier, identifier)
    return bool(data[identifier] if name.startswith("[") else getattr(data, name))


def _input_items(group):
    """The group's input sockets but the geometry."""
    return [item for item in group.interface.items_tree if _is_input(item)]


def _is_input(item):
    """Whether a node group interface item is an input socket other than the geometry."""
    return item.item_type == "SOCKET" and item.in_out == "INPUT" and item.socket_type != "NodeSocketGeometry"


def release_group(group, successor=None):
    """Remove a node group of this add-on once no modifier uses it (a linked duplicate may still); its
    ``successor``, the group that replaced it, then takes its name."""
    if group is None:
        return
    used = any(modifier.type == "NODES" and modifier.node_group == group
               for obj in bpy.data.objects for modifier in obj.modifiers)
    if not used:
        name = group.name
        bpy.data.node_groups.remove(group)
        if successor is not None:
            successor.name = name


def find_modifier(mesh_obj):
    """The LBC modifier of a bound object, or None (the user may have removed it)."""
    group = mesh_obj.lbc.node_group
    for modifier in mesh_obj.modifiers:
        if modifier.type == "NODES" and group is not None and modifier.node_group == group:
            return modifier
    return None


def rebind_all_targets(cage_obj, objects):
    """What Rebind All binds again: (targets, left_out).

    ``targets``: a (mesh, cage, options) triple for each of ``objects`` bound to ``cage_obj`` that still has its LBC
    modifier; ``left_out``: "'Name' left as it was: …" for each one whose modifier was removed or applied. Binding
    those again would put the deformer back on a mesh whose artist replaced it (a copy moved to Mesh Deform would be
    deformed twice, an applied one would take its deformation as rest); Rebind of that mesh alone still does.
    """
    targets, left_out = [], []
    for mesh_obj in bound_to(cage_obj, objects):
        if find_modifier(mesh_obj) is None:
            left_out.append(f"'{mesh_obj.name}' left as it was: its LBC modifier was removed or applied (select it "
                            "and Rebind to add the modifier back, or Unbind it)")
        else:
            targets.append((mesh_obj, cage_obj, mesh_obj.lbc.bind_options()))
    return targets, left_out


def detach(mesh_obj):
    """Remove the modifier and its node group (kept while a linked duplicate's modifier uses it)."""
    modifier = find_modifier(mesh_obj)
    if modifier is not None:
        remove_modifier(mesh_obj, modifier)
    group = mesh_obj.lbc.node_group
    mesh_obj.lbc.node_group = None
    release_group(group)


def remove_modifier(mesh_obj, modifier):
    """Remove a Geometry Nodes modifier of this add-on from ``mesh_obj``, its Cage input cleared first: Blender 5.2
    removes a modifier without giving back the user its Object input held, which would keep a deleted cage alive."""
    identifier = input_identifier(modifier, "Cage") if modifier.node_group is not None else None
    if identifier is not None:
        set_raw_inputs(modifier, {identifier: None})
    mesh_obj.modifiers.remove(modifier)


def set_enabled(mesh_obj, enabled):
    """Switch the deformation on or off through the modifier's "Enabled" input; True when it changed."""
    modifier = find_modifier(mesh_obj)
    if modifier is None:
        return False
    if is_enabled(modifier) == enabled:
        return False
    set_inputs(modifier, {"Enabled": enabled})
    mesh_obj.update_tag()
    return True


def evaluated_cage(cage_obj, depsgraph):
    """Topology fingerprints (:func:`geometry.topology_fingerprints`) and (n, 3) vertex positions of the cage as the
    deformer sees it (modifiers applied)."""
    cage_eval = cage_obj.evaluated_get(depsgraph)
    mesh = cage_eval.to_mesh()
    try:
        return geometry.topology_fingerprints(mesh), geometry.vertex_positions(mesh)
    finally:
        cage_eval.to_mesh_clear()


def _evaluated_once(cage_obj, depsgraph, cages):
    """:func:`evaluated_cage`, kept in ``cages`` (a dict by cage name, or None to keep nothing) for the next call."""
    if cages is None:
        return evaluated_cage(cage_obj, depsgraph)
    if cage_obj.name_full not in cages:
        cages[cage_obj.name_full] = evaluated_cage(cage_obj, depsgraph)
    return cages[cage_obj.name_full]


def displacement(mesh_obj, depsgraph, cages=None):
    """(m, 3) float array: what the LBC modifier adds to each vertex of a bound mesh now, in the mesh's local space:
    its node group's Σ w_k c_k minus the rest, times Strength and the vertex group's mask, from the stored slots and
    the cage as the depsgraph evaluates it (float64: within float32 rounding of the modifier's own sum). ``cages``:
    as for :func:`diagnose`."""
    values = inputs(find_modifier(mesh_obj))
    cage = mesh_obj.lbc.cage
    matrix = geometry.cage_to_mesh_matrix(cage.evaluated_get(depsgraph), mesh_obj.evaluated_get(depsgraph))
    cage_local = geometry.transform(matrix, _evaluated_once(cage, depsgraph, cages)[1])
    index, weight = storage.read(mesh_obj.data)
    offsets = storage.rest_offsets(index, weight, cage_local) - storage.read_rest(mesh_obj.data)
    mask = geometry.vertex_group_mask(mesh_obj, values["Vertex Group"], values["Invert Vertex Group"])
    return offsets * (values["Strength"] * mask)[:, None]


def rest_moved(mesh):
    """Whether a bound mesh's vertices were moved as a whole since binding: a sample of them (:data:`REST_SAMPLES`)
    is an affine image, other than the identity, of the rest positions the weights reproduce. Apply Transforms does
    this to the mesh data, and the deformer would add the cage's displacement to a rest it no longer has: a jump.
    Edits of part of the mesh (sculpting) are no affine image. Vertices outside the cage rest at their closest point
    inside, which can be an affine image of them (a box outside a box): a mesh whose sampled vertices all lie outside
    could be flagged, which is why a mesh wholly outside is refused at bind time."""
    rest_attribute = mesh.attributes.get(storage.REST_NAME)
    count = len(mesh.vertices)
    if rest_attribute is None or count < 4 or len(rest_attribute.data) != count:
        return False
    sample = np.unique(np.linspace(0, count - 1, min(count, REST_SAMPLES)).astype(int)).tolist()
    rest = np.array([rest_attribute.data[i].vector[:] for i in sample])
    now = np.array([mesh.vertices[i].co[:] for i in sample])
    return moved_affinely(rest, now)


def moved_affinely(before, after, tolerance=1e-5):
    """Whether (k, 3) points ``after`` are an affine image of ``before`` other than the identity, both to
    ``tolerance`` × the size of ``before`` plus the float32 rounding of the positions (far from the origin or scaled
    up, the rounding of the moved positions alone exceeds 1e-5 of the mesh's size), the fit leaving at most
    UNEXPLAINED_SHARE of the largest change unexplained."""
    size = float(np.linalg.norm(np.ptp(before, axis=0)))
    allowed = tolerance * size + FLOAT32_ROUNDING * (np.abs(before).max() + np.abs(after).max())
    change = np.abs(after - before).max()
    if change <= allowed:
        return False
    design = np.c_[before, np.ones(len(before))]
    fit, *_ = np.linalg.lstsq(design, after, rcond=None)
    unexplained = np.abs(design @ fit - after).max()
    return bool(unexplained <= allowed and unexplained <= UNEXPLAINED_SHARE * change)


def welded_apart(welded, positions):
    """The first (copy, kept) pair of cage vertices welded at bind time that are now apart, or None.

    ``welded``: the binding's "copy:kept,..." pairs; apart means farther than lbc_core's POSED_APART × the cage's size,
    the tolerance of ``lbc deform``.
    """
    pairs = read_welded(welded)
    if not len(pairs):
        return None
    size = float(np.linalg.norm(np.ptp(positions, axis=0)))
    offset = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    apart = np.flatnonzero(offset > POSED_APART * size)
    return tuple(pairs[apart[0]].tolist()) if len(apart) else None


def status(mesh_obj, depsgraph):
    """Whether a bound object's deformer can work, and if not, why.

    Returns
    -------
    (ok: bool, message: str)
    """
    cause, message = diagnose(mesh_obj, depsgraph)
    return cause is None, message


def held_off_warning(mesh_obj):
    """After a bind: why its deformer cannot work as the stack stands (e.g. a Rebind below a modifier that changes the
    vertex count, which Bind's own modifier, added at the top, never is), as a warning; None when it follows."""
    ok, message = status(mesh_obj, bpy.context.evaluated_depsgraph_get())
    return None if ok else f"bound, but the deformer is held off: {message[:1].lower()}{message[1:]}"


def diagnose(mesh_obj, depsgraph, cages=None):
    """Why a bound object's deformer cannot work: (cause, message), cause None when it works.

    ``cause`` is one of "modifier", "weights", "mesh vertices", "rest moved" (:func:`rest_moved`), "cage deleted",
    "cage type", "cage vertices", "topology", "welded apart", "modifier above" (one that can change the vertex
    count), "modifier error" (an error the node group raised for what only it sees), "modifier off" (switched off in
    the viewport by the artist). A cage with other vertices in
    renders still follows (cause None), its message says so. Only the causes in :data:`STOPPED_HERE` need the add-on
    to stop the deformer; the node group itself stops for the others.
    ``cages``: a dict keeping each cage's :func:`evaluated_cage` for the next bindings checked with the same depsgraph,
    so that the meshes bound to one cage (a body, its clothes, its eyes) evaluate and hash it once.
    """
    settings = mesh_obj.lbc
    modifier = find_modifier(mesh_obj)
    if modifier is None:
        return "modifier", (
            "The LBC modifier was removed or applied: Unbind to remove the weights it left in the mesh (the mesh keeps "
            "its shape), or Rebind"
        )
    count = len(mesh_obj.data.vertices)
    # 0: bound by a version of the add-on that did not record it. Checked first: a Join changes both the vertex count
    # and the slots stored, and the vertex count is what the artist did.
    if settings.mesh_vertex_count and count != settings.mesh_vertex_count:
        return "mesh vertices", (
            f"The mesh has {count} vertices, it was bound with {settings.mesh_vertex_count}: it stays undeformed. "
            "Rebind"
        )
    if storage.slot_count(mesh_obj.data) != settings.slots:
        return "weights", "The cached weights are missing from the mesh data: Rebind"
    if rest_moved(mesh_obj.data):
        return "rest moved", (
            "The mesh's vertices were moved as a whole since binding (Apply Transforms, or all of them moved in Edit "
            "Mode): it stays at rest, undeformed (following the cage it would jump). Undo the move, or put the cage "
            "in its rest pose and Rebind (Rebind binds to the cage as it is)"
        )
    cage = settings.cage
    if cage is None:
        return "cage deleted", (
            "The cage was deleted: the mesh is back at rest. Select it, then a new cage (active), and Bind; or Unbind"
        )
    if cage.type != "MESH":
        return "cage type", f"The cage '{cage.name}' is no longer a mesh: Rebind with a mesh cage"
    topologies, positions = _evaluated_once(cage, depsgraph, cages)
    count = len(positions)
    if count != settings.cage_vertex_count:
        modifiers = geometry.cage_modifiers_note(cage)
        return "cage vertices", (
            f"The cage '{cage.name}' has {count} vertices{f' ({modifiers})' if modifiers else ''}, it was bound with "
            f"{settings.cage_vertex_count}: the mesh stays undeformed. Rebind"
        )
    if settings.cage_topology not in topologies:
        return "topology", (
            f"The topology of the cage '{cage.name}' changed since binding (same vertex count): the mesh stays "
            "undeformed. Rebind"
        )
    apart = welded_apart(settings.welded, positions)
    if apart is not None:
        return "welded apart", (
            f"Cage vertices {apart[0]} and {apart[1]} of '{cage.name}' were one point when bound and are now apart: "
            "the mesh stays at rest. Move them together again, or merge them (Merge by Distance) and Rebind"
        )
    # What only the modifier sees (Blender 4.3 and newer; the causes above are ruled out): the vertex count reaching
    # it differs. While the add-on holds the deformer off, its warning is the add-on's own, and the cause is gone.
    warnings = getattr(modifier, "node_warnings", ()) if is_enabled(modifier) else ()
    messages = [warning.message[len("LBC: "):] for warning in warnings if warning.message.startswith("LBC: ")]
    # Which modifier: one above that can change the count, as the modifier's error confirms (4.2 has no Warning node
    # to confirm it; there the modifier's type alone says so).
    above = _vertex_count_modifier_above(mesh_obj, modifier, depsgraph)
    if above is not None and (messages or not _has_warning_nodes(modifier.node_group)):
        return "modifier above", (
            f"The modifier '{above.name}' above '{modifier.name}' changes the mesh's vertex count: the mesh stays "
            f"undeformed. Move '{modifier.name}' to the top of the stack"
        )
    if messages:
        return "modifier error", messages[0][:1].upper() + messages[0][1:]
    if not modifier.show_viewport:
        return "modifier off", (
            f"The modifier '{modifier.name}' is switched off in the viewport (its screen icon): the mesh stays at rest "
            f"there{'' if modifier.show_render else ' and in renders'}. Switch it on to follow '{cage.name}'"
        )
    difference = geometry.render_difference(cage)
    if difference is not None:
        return None, (f"Following '{cage.name}' in the viewport, but renders leave the mesh undeformed: the cage's "
                      f"{difference}. Make them the same and Rebind")
    return None, f"Following '{cage.name}'"


def _vertex_count_modifier_above(mesh_obj, modifier, depsgraph):
    """The first modifier shown in the viewport above ``modifier`` that can change the vertex count, or None. A
    Geometry Nodes modifier (whose tree may keep the count) only where the evaluated mesh has another count than the
    mesh data and no modifier below could have changed it."""
    stack = list(mesh_obj.modifiers)
    position = stack.index(modifier)
    for other in filter(geometry.may_change_vertex_count, stack[:position]):
        if other.type != "NODES":
            return other
        if not any(map(geometry.may_change_vertex_count, stack[position + 1:])) and (
                len(mesh_obj.evaluated_get(depsgraph).data.vertices) != len(mesh_obj.data.vertices)):
            return other
    return None


_last_messages = {}  # object session_uid -> the last status printed, so a problem is reported once, not per redraw
# The session_uids of cages seen in a collection. A cage in none was deleted (X) only if it was in one before: a cage
# that came in with an appended or linked mesh, indirectly, was never in one, and Mesh Deform follows such a cage.
_cages_in_scene = set()


def note_cage_in_scene(cage):
    """Remember that ``cage`` was in a collection: from now on, leaving every collection means it was deleted."""
    _cages_in_scene.add(cage.session_uid)


def check_bindings(depsgraph, changed=None):
    """Check every bound object of the depsgraph's scene; stop or resume its deformation; print changes of state.

    ``changed``: when given, the names of the objects whose geometry changed; only bindings involving one of them
    (or whose cage is gone) are checked. Cages deleted by the user (no longer in any collection, having been in one)
    are let go first (:func:`forget_cage`).
    """
    bound = [obj for obj in depsgraph.scene.objects if is_bound(obj)]
    deleted = []
    for obj in bound:
        cage = obj.lbc.cage
        if cage is None or cage in deleted:
            continue
        if cage.users_collection:
            note_cage_in_scene(cage)
        elif cage.session_uid in _cages_in_scene:
            deleted.append(cage)
    for cage in deleted:
        forget_cage(cage)
    cages = {}
    for obj in bound:
        cage = obj.lbc.cage
        if changed is not None and cage is not None and not {obj.name_full, cage.name_full} & changed:
            continue
        cause, message = diagnose(obj, depsgraph, cages)
        set_enabled(obj, cause not in STOPPED_HERE)
        if obj.lbc.status != message:  # writing the same value would trigger another depsgraph update
            obj.lbc.state = "FOLLOWING" if cause is None else "STOPPED"
            obj.lbc.status = message
        if _last_messages.get(obj.session_uid) != message:
            _last_messages[obj.session_uid] = message
            if cause is not None and cause not in ARTISTS_CHOICE:
                print(f"LBC: {obj.name}: {message}")


def forget_cage(cage, defer=None):
    """Let go of a cage the user deleted, as Blender's Mesh Deform does.

    Deleting an object (X) only unlinks it from its scene while something else counts as its user, and the
    binding's pointer and the modifier's Cage input both do: the cage would live on off-scene with the meshes
    following it. Every binding to ``cage`` drops it (the node group then leaves the mesh at rest), and the cage is
    removed once nothing else uses it (:func:`remove_if_orphan`). This runs in a depsgraph handler: in a session with
    an event loop the removal waits for a timer, outside the handler; ``defer`` None means "when there is one".
    """
    _cages_in_scene.discard(cage.session_uid)
    for obj in bpy.data.objects:
        if is_bound(obj) and obj.lbc.cage == cage:
            obj.lbc.cage = None
            modifier = find_modifier(obj)
            if modifier is not None:
                set_inputs(modifier, {"Cage": None})
                obj.update_tag()
    if defer is None:
        defer = not bpy.app.background
    if defer:
        bpy.app.timers.register(functools.partial(remove_if_orphan, cage.name_full), first_interval=0.0)
    else:
        remove_if_orphan(cage.name_full)


def remove_if_orphan(name):
    """Remove the object called ``name`` if it is in no collection and nothing uses it any more."""
    obj = bpy.data.objects.get(name)
    if obj is not None and obj.users == 0 and not obj.users_collection:
        bpy.data.objects.remove(obj)


@persistent
def _on_depsgraph_update(scene, depsgraph):
    # Hashing a cage's topology is only needed when its geometry changed; bindings whose cage is gone are cheap to
    # check and are checked on every update (deleting an object reports no geometry update).
    changed = {
        update.id.original.name_full
        for update in depsgraph.updates
        if isinstance(update.id, bpy.types.Object) and update.is_updated_geometry
    }
    check_bindings(depsgraph, changed)


@persistent
def _on_load_or_undo(*_args):
    check_bindings(bpy.context.evaluated_depsgraph_get())


@persistent
def _on_load(*_args):
    refresh_outdated_groups()
    _on_load_or_undo()


def refresh_outdated_groups():
    """Rebuild, once a file is opened, the node groups of bound meshes that do not suit this Blender (:func:`outdated`:
    a file moved between 4.2 and a newer line), for the same counts, the modifier's inputs kept. Linked data is left
    to its own file. Returns the refreshed objects."""
    refreshed = []
    for obj in bpy.data.objects:
        modifier = find_modifier(obj) if is_bound(obj) else None
        group = None if modifier is None else modifier.node_group
        if group is None or not outdated(group) or obj.library or group.library or obj.lbc.cage is None:
            continue
        _, weight = storage.read(obj.data)
        kept = inputs(modifier)
        modifier, replaced = attach(obj, obj.lbc.cage, weight.shape[1], obj.lbc.cage_vertex_count,
                                    kept.get("Mesh Vertices", len(obj.data.vertices)), shared_slot_count(weight))
        # The add-on's stop for a changed topology stays as it was (attach enables the new group).
        set_inputs(modifier, {"Enabled": kept.get("Enabled", True)})
        obj.lbc.node_group = modifier.node_group
        release_group(replaced, modifier.node_group)
        refreshed.append(obj)
    return refreshed


_HANDLERS = (
    (bpy.app.handlers.depsgraph_update_post, _on_depsgraph_update),
    (bpy.app.handlers.load_post, _on_load),
    (bpy.app.handlers.undo_post, _on_load_or_undo),
    (bpy.app.handlers.redo_post, _on_load_or_undo),
)


def register():
    for handlers, handler in _HANDLERS:
        if handler not in handlers:
            handlers.append(handler)


def unregister():
    for handlers, handler in _HANDLERS:
        if handler in handlers:
            handlers.remove(handler)
