"""The deformer on a bound mesh: its Geometry Nodes modifier ("LBC Deform", whose node group :mod:`node_group`
builds), added, kept or removed, and its inputs read and written by name on every Blender line; what it adds to the
mesh now (:func:`displacement`).
"""

import bpy

from . import geometry, node_group, storage
from .properties import bound_to

MODIFIER_NAME = "LBC Deform"
# The modifier inputs that are the artist's (kept when the mesh is bound again); the others are the add-on's.
USER_INPUTS = ("Strength", "Vertex Group", "Invert Vertex Group")


def attach(mesh_obj, cage_obj, slots, cage_vertex_count, mesh_vertex_count, shared_slots=None):
    """Give ``mesh_obj`` the deformer for a new binding.

    A bound object keeps its LBC modifier (its place in the stack, name, Strength, vertex group) with a new node
    group; otherwise a new modifier goes first in the stack (the weights belong to the mesh's own vertices, before
    any other modifier moves them).

    ``shared_slots``: how many of the ``slots`` stored on the mesh every vertex evaluates (see
    :func:`node_group.build_node_group`; :func:`node_group.shared_slot_count` of the weights written, for a bind);
    None, every slot.

    The modifier's node group is kept when it was made for the same counts and layout (:func:`node_group.layout`).

    Returns
    -------
    (modifier, replaced node group or None)
        The replaced group is still in the file: :func:`release_group` removes it once the binding is complete.
    """
    layout = node_group.layout(slots, cage_vertex_count, mesh_vertex_count, shared_slots)
    modifier = find_modifier(mesh_obj)
    if modifier is None:
        modifier = mesh_obj.modifiers.new(MODIFIER_NAME, "NODES")
        mesh_obj.modifiers.move(len(mesh_obj.modifiers) - 1, 0)
    replaced, kept = modifier.node_group, inputs(modifier)
    if replaced is not None and replaced.get(node_group.LAYOUT_KEY) == layout and not node_group.outdated(replaced):
        replaced = None  # made for the same counts and layout in this Blender line: kept as it is
    else:
        modifier.node_group = node_group.build_node_group(slots, cage_vertex_count, mesh_vertex_count, shared_slots)
        modifier.node_group[node_group.LAYOUT_KEY] = layout
    group = modifier.node_group
    # Every input is set: a value Blender kept from the replaced group under the same identifier may be another one's.
    defaults = {item.name: item.default_value for item in _input_items(group) if item.socket_type != "NodeSocketObject"}
    set_inputs(modifier, {**defaults, **{name: kept[name] for name in USER_INPUTS if name in kept}, "Cage": cage_obj,
                          "Cage Vertices": cage_vertex_count, "Mesh Vertices": mesh_vertex_count, "Enabled": True})
    return modifier, replaced


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


def displacement(mesh_obj, depsgraph, cages=None):
    """(m, 3) float array: what the LBC modifier adds to each vertex of a bound mesh now, in the mesh's local space:
    its node group's Σ w_k c_k minus the rest, times Strength and the vertex group's mask, from the stored slots and
    the cage as the depsgraph evaluates it (float64: within float32 rounding of the modifier's own sum). ``cages``:
    as for :func:`diagnosis.diagnose`."""
    values = inputs(find_modifier(mesh_obj))
    cage = mesh_obj.lbc.cage
    matrix = geometry.cage_to_mesh_matrix(cage.evaluated_get(depsgraph), mesh_obj.evaluated_get(depsgraph))
    cage_local = geometry.transform(matrix, geometry.evaluated_cage_once(cage, depsgraph, cages)[1])
    index, weight = storage.read(mesh_obj.data)
    offsets = storage.rest_offsets(index, weight, cage_local) - storage.read_rest(mesh_obj.data)
    mask = geometry.vertex_group_mask(mesh_obj, values["Vertex Group"], values["Invert Vertex Group"])
    return offsets * (values["Strength"] * mask)[:, None]
