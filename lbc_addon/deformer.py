"""The live deformer: a Geometry Nodes modifier built from Python, and the checks that keep it honest.

The node group reads the evaluated cage through Object Info in relative mode (so the cage's positions arrive in the
mesh's local space, following its animation, armature, drivers), samples the cage position of each of the K slots,
and moves every vertex by Σ w_k c_k − rest (see :mod:`storage`). Geometry Nodes is compiled C++ evaluated in the
depsgraph: it runs in renders, in the viewport while the cage is edited, and in files opened without this add-on.

When the cage's vertex count differs from the one bound (or the cage is gone), the node group itself passes the mesh
through undeformed and shows an error on the modifier: that works without the add-on. A change of topology that keeps
the vertex count (faces rebuilt, vertices reordered) is caught by :func:`check_bindings`, which clears the
modifier's "Enabled" input; the panel says why and offers Rebind.
"""

import bpy
from bpy.app.handlers import persistent

from . import geometry, storage
from .properties import is_bound

MODIFIER_NAME = "LBC Deform"
GROUP_NAME = "LBC Deform"

_COLUMN = 220  # node editor spacing, for a readable node group


def build_node_group(slots):
    """A new node group deforming by ``slots`` (index, weight) attribute pairs."""
    group = bpy.data.node_groups.new(GROUP_NAME, "GeometryNodeTree")
    group.is_modifier = True
    interface = group.interface
    interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    interface.new_socket("Cage", in_out="INPUT", socket_type="NodeSocketObject")
    count = interface.new_socket("Cage Vertices", in_out="INPUT", socket_type="NodeSocketInt")
    count.description = "Vertex count of the cage at bind time; any other count stops the deformation"
    enabled = interface.new_socket("Enabled", in_out="INPUT", socket_type="NodeSocketBool")
    enabled.default_value = True
    enabled.description = "Cleared by the LBC add-on when the cage's topology changed since binding"
    interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")

    nodes, links = group.nodes, group.links
    group_in = nodes.new("NodeGroupInput")
    group_out = nodes.new("NodeGroupOutput")
    group_out.location = (_COLUMN * 7, 0)

    cage = nodes.new("GeometryNodeObjectInfo")
    cage.transform_space = "RELATIVE"
    cage.location = (_COLUMN, 300)
    links.new(group_in.outputs["Cage"], _input(cage, "Object"))
    cage_geometry = cage.outputs["Geometry"]

    position = nodes.new("GeometryNodeInputPosition")
    position.location = (_COLUMN, -100)
    total = None
    for slot in range(slots):
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
        if total is None:
            total = scaled.outputs["Vector"]
        else:
            add = _vector_math(nodes, "ADD", (_COLUMN * 5, y))
            links.new(total, _inputs(add, "Vector")[0])
            links.new(scaled.outputs["Vector"], _inputs(add, "Vector")[1])
            total = add.outputs["Vector"]

    rest = _named_attribute(nodes, "FLOAT_VECTOR", storage.REST_NAME, (_COLUMN * 4, 150))
    displacement = _vector_math(nodes, "SUBTRACT", (_COLUMN * 5, 150))
    links.new(total, _inputs(displacement, "Vector")[0])
    links.new(rest.outputs["Attribute"], _inputs(displacement, "Vector")[1])
    set_position = nodes.new("GeometryNodeSetPosition")
    set_position.location = (_COLUMN * 6, 150)
    links.new(group_in.outputs["Geometry"], _input(set_position, "Geometry"))
    links.new(displacement.outputs["Vector"], _input(set_position, "Offset"))

    stop = _stop_condition(group, group_in, cage_geometry)
    switch = nodes.new("GeometryNodeSwitch")
    switch.input_type = "GEOMETRY"
    switch.location = (_COLUMN * 6.5, 400)
    links.new(stop, _input(switch, "Switch"))
    links.new(set_position.outputs["Geometry"], _input(switch, "False"))
    links.new(group_in.outputs["Geometry"], _input(switch, "True"))
    links.new(switch.outputs["Output"], _input(group_out, "Geometry"))
    return group


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


def _stop_condition(group, group_in, cage_geometry):
    """The boolean output that is true when the mesh must stay undeformed; each reason raises a modifier warning."""
    nodes, links = group.nodes, group.links
    size = nodes.new("GeometryNodeAttributeDomainSize")
    size.component = "MESH"
    size.location = (_COLUMN * 2, 500)
    links.new(cage_geometry, _input(size, "Geometry"))
    same = nodes.new("FunctionNodeCompare")
    same.data_type = "INT"
    same.operation = "NOT_EQUAL"
    same.location = (_COLUMN * 3, 500)
    links.new(size.outputs["Point Count"], _input(same, "A"))
    links.new(group_in.outputs["Cage Vertices"], _input(same, "B"))
    changed = _warning(
        nodes,
        "LBC: the cage is missing or its vertex count changed since binding; the mesh is left undeformed. "
        "Rebind, or restore the cage",
        (_COLUMN * 4, 500),
    )
    links.new(same.outputs["Result"], _input(changed, "Show"))

    disabled = nodes.new("FunctionNodeBooleanMath")
    disabled.operation = "NOT"
    disabled.location = (_COLUMN * 3, 650)
    links.new(group_in.outputs["Enabled"], _inputs(disabled, "Boolean")[0])
    stopped = _warning(
        nodes,
        "LBC: the cage's topology changed since binding; the mesh is left undeformed. Rebind in the LBC panel",
        (_COLUMN * 4, 650),
    )
    links.new(disabled.outputs["Boolean"], _input(stopped, "Show"))

    either = nodes.new("FunctionNodeBooleanMath")
    either.operation = "OR"
    either.location = (_COLUMN * 5, 550)
    links.new(changed.outputs["Show"], _inputs(either, "Boolean")[0])
    links.new(stopped.outputs["Show"], _inputs(either, "Boolean")[1])
    return either.outputs["Boolean"]


def _warning(nodes, message, location):
    node = nodes.new("GeometryNodeWarning")
    node.warning_type = "ERROR"
    _input(node, "Message").default_value = message
    node.location = location
    return node


def _input_identifier(group, name):
    for item in group.interface.items_tree:
        if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.name == name:
            return item.identifier
    raise KeyError(name)


def attach(mesh_obj, cage_obj, slots, cage_vertex_count):
    """Add the deformer as the first modifier of ``mesh_obj`` (the weights belong to the mesh's own vertices).

    Returns the modifier.
    """
    group = build_node_group(slots)
    modifier = mesh_obj.modifiers.new(MODIFIER_NAME, "NODES")
    modifier.node_group = group
    modifier[_input_identifier(group, "Cage")] = cage_obj
    modifier[_input_identifier(group, "Cage Vertices")] = cage_vertex_count
    modifier[_input_identifier(group, "Enabled")] = True
    mesh_obj.modifiers.move(len(mesh_obj.modifiers) - 1, 0)
    return modifier


def find_modifier(mesh_obj):
    """The LBC modifier of a bound object, or None (the user may have removed it)."""
    group = mesh_obj.lbc.node_group
    for modifier in mesh_obj.modifiers:
        if modifier.type == "NODES" and group is not None and modifier.node_group == group:
            return modifier
    return None


def detach(mesh_obj):
    """Remove the modifier and its node group."""
    modifier = find_modifier(mesh_obj)
    if modifier is not None:
        mesh_obj.modifiers.remove(modifier)
    group = mesh_obj.lbc.node_group
    mesh_obj.lbc.node_group = None
    # A duplicated bound object shares the node group: keep it while another modifier uses it.
    if group is not None and not any(
        modifier.type == "NODES" and modifier.node_group == group for obj in bpy.data.objects for modifier in obj.modifiers
    ):
        bpy.data.node_groups.remove(group)


def set_enabled(mesh_obj, enabled):
    """Switch the deformation on or off through the modifier's "Enabled" input; True when it changed."""
    modifier = find_modifier(mesh_obj)
    if modifier is None:
        return False
    key = _input_identifier(modifier.node_group, "Enabled")
    if bool(modifier[key]) == enabled:
        return False
    modifier[key] = enabled
    mesh_obj.update_tag()
    return True


def evaluated_cage_topology(cage_obj, depsgraph):
    """Topology fingerprint and vertex count of the cage as the deformer sees it (modifiers applied)."""
    cage_eval = cage_obj.evaluated_get(depsgraph)
    mesh = cage_eval.to_mesh()
    try:
        return geometry.topology_fingerprint(mesh), len(mesh.vertices)
    finally:
        cage_eval.to_mesh_clear()


def status(mesh_obj, depsgraph):
    """Whether a bound object's deformer can work, and if not, why.

    Returns
    -------
    (ok: bool, message: str)
    """
    settings = mesh_obj.lbc
    if find_modifier(mesh_obj) is None:
        return False, "The LBC modifier was removed: Unbind to clean up, or Rebind"
    if storage.slot_count(mesh_obj.data) != settings.slots:
        return False, "The cached weights are missing from the mesh data: Rebind"
    cage = settings.cage
    if cage is None:
        return False, "The cage object was deleted: the mesh stays undeformed. Pick a cage and Rebind, or Unbind"
    if cage.type != "MESH":
        return False, f"The cage '{cage.name}' is no longer a mesh: Rebind with a mesh cage"
    topology, count = evaluated_cage_topology(cage, depsgraph)
    if count != settings.cage_vertex_count:
        return False, (
            f"The cage '{cage.name}' has {count} vertices, the binding was made for {settings.cage_vertex_count}: "
            "the mesh stays undeformed. Rebind"
        )
    if topology != settings.cage_topology:
        return False, f"The topology of the cage '{cage.name}' changed since binding: the mesh stays undeformed. Rebind"
    return True, f"Following '{cage.name}'"


_last_messages = {}  # object session_uid -> the last status printed, so a problem is reported once, not per redraw


def check_bindings(depsgraph, changed=None):
    """Check every bound object of the depsgraph's scene; stop or resume its deformation; print changes of state.

    ``changed``: when given, the names of the objects whose geometry changed; only bindings involving one of them
    (or whose cage is gone) are checked.
    """
    for obj in depsgraph.scene.objects:
        if not is_bound(obj):
            continue
        cage = obj.lbc.cage
        if changed is not None and cage is not None and not {obj.name_full, cage.name_full} & changed:
            continue
        ok, message = status(obj, depsgraph)
        set_enabled(obj, ok)
        if obj.lbc.status != message:  # writing the same value would trigger another depsgraph update
            obj.lbc.status = message
        if _last_messages.get(obj.session_uid) != message:
            _last_messages[obj.session_uid] = message
            if not ok:
                print(f"LBC: {obj.name}: {message}")


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


_HANDLERS = (
    (bpy.app.handlers.depsgraph_update_post, _on_depsgraph_update),
    (bpy.app.handlers.load_post, _on_load_or_undo),
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
