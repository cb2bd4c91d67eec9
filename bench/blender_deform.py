"""Per-frame cost of the LBC deformer against Blender's Mesh Deform on the same mesh, cage and poses.

    PYTHONPATH=. .venv/bin/python bench/blender_deform.py [--frames 31] [--scenes suzanne,gargoyle]
        [--modes edit,playback] [--thin 0.002:0,0.005:12] [--sums chain,fma,fma-vector]
        [--shared 0,11,12] [--trees direct,pairs,points,displacement,compact-tail,
        sorted,triplets] [--reference-cells 16000] [--handler-off] [--smoothness 0,1]

Headless, with the bpy module, everything in one process. Each variant is its own copy of the mesh (its own mesh
data, so its own attributes) and is linked into the scene only while it is measured, so every timed update evaluates
one deformer. Frames are interleaved: in each round every variant gets the same new pose of the cage, in a rotating
order, and the time of one frame is recorded, as wall time and as the process's CPU time. Two kinds of frame
(``--modes``): "edit", the depsgraph update that follows an edit of the cage's vertices (``evaluated_depsgraph_get``,
the add-on's depsgraph handler included), and "playback", ``scene.frame_set`` to the next frame of a cage animated by
shape keys (what playback and rendering cost; Blender calls no depsgraph update handler on a frame change). Printed:
the medians over the rounds, the lower and upper quartiles, and the load average before and after.

Scenes: Suzanne subdivided to 48,612 vertices in a 56-vertex box cage, and the demo's gargoyle (two Catmull-Clark
levels: 64,130 vertices) in its 67-vertex cage L10; "suzanne507", Suzanne as Blender makes her (507 vertices) in the
same cage, shows the deformer's cost that does not grow with the vertices; "cylinder", a 50,882-vertex UV sphere in
Blender's default Cylinder. Variants: no deformer, Mesh Deform (precision 5), LBC bound with
the add-on's defaults, LBC with every weight (bound with a threshold of 1e-12: nothing thinned), LBC with every
weight thinned by other thresholds and caps (``--thin floor:cap``; see :func:`lbc_core.evaluate.thinning.thin_weights`),
LBC with its weighted sum built in another shape (``--sums``; see :func:`rebuild_sum`), the default's weights with
another number of slots evaluated for every vertex (``--shared``; see :func:`lbc_addon.node_group.build_node_group`),
and the default's tree changed by another lever (``--trees``; see :func:`rebuild_tree`, and :func:`triplet_variant`
for "triplets"). ``--reference-cells`` also
prints how far the binding with every weight is from a finer one: the yardstick for the error thinning makes.
``--handler-off`` also measures the default binding with the add-on's depsgraph handler (its check of every binding
after a cage edit) unregistered. ``--smoothness`` also binds copies at other Smoothness values (the add-on's other
defaults).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import bpy  # noqa: E402

from helpers.blender_scenes import (  # noqa: E402
    evaluated_positions,
    gargoyle_scene,
    positions,
    register_addon,
    reset,
    suzanne_in_box_scene,
)
import scipy.sparse as sp  # noqa: E402

from lbc_addon import api, deformer, handlers, node_group, storage  # noqa: E402
from lbc_core.evaluate.thinning import thin_weights  # noqa: E402

EVERY_WEIGHT = 1e-12  # a Threshold that thins nothing


def gargoyle_subdivided():
    mesh, cage = gargoyle_scene("L10")
    subsurf = mesh.modifiers.new("Subdivision", "SUBSURF")
    subsurf.levels = 2
    with bpy.context.temp_override(object=mesh, active_object=mesh):
        bpy.ops.object.modifier_apply(modifier=subsurf.name)
    return mesh, cage


def sphere_in_cylinder():
    """A new user's scene: a 50,882-vertex UV sphere (radius 0.5) in Blender's default Cylinder, whose 32-gon caps
    reach every point (each vertex feels all 64 cage vertices)."""
    reset()
    bpy.ops.mesh.primitive_cylinder_add()
    cage = bpy.context.active_object
    bpy.ops.mesh.primitive_uv_sphere_add(segments=320, ring_count=160, radius=0.5)
    return bpy.context.active_object, cage


SCENES = {"suzanne": suzanne_in_box_scene, "gargoyle": gargoyle_subdivided,
          "suzanne507": lambda: suzanne_in_box_scene(cuts=0), "cylinder": sphere_in_cylinder}


def pose(rest, phase):
    """A smooth, non-affine pose of the cage: a twist about z and a bulge that vary with ``phase``."""
    center = rest.mean(axis=0)
    extent = np.ptp(rest, axis=0)
    relative = rest - center
    height = relative[:, 2] / extent[2]
    angle = 0.4 * np.sin(phase) * height
    cos, sin = np.cos(angle), np.sin(angle)
    posed = relative.copy()
    posed[:, 0] = cos * relative[:, 0] - sin * relative[:, 1]
    posed[:, 1] = sin * relative[:, 0] + cos * relative[:, 1]
    posed *= 1 + 0.15 * np.cos(phase) * (0.5 - np.abs(height))[:, None]
    return center + posed


def set_cage(cage, points):
    cage.data.vertices.foreach_set("co", np.asarray(points, dtype=np.float32).ravel())
    cage.data.update()


def copy_object(mesh, name):
    """An unlinked copy of ``mesh`` with its own mesh data (attributes included) and no LBC state."""
    copy = mesh.copy()
    copy.data = mesh.data.copy()
    copy.name = name
    if copy.is_property_set("lbc"):
        copy.property_unset("lbc")
    copy.modifiers.clear()
    return copy


def lbc_variant(bound, cage, name, thinning=None, sum_form=None, shared_slots=None, tree=None):
    """A copy of the bound mesh deformed by LBC, its weights thinned by ``thinning`` = (floor, cap) (None: as
    bound; see :func:`lbc_core.evaluate.thinning.thin_weights`), its weighted sum built as ``sum_form`` (see
    :func:`rebuild_sum`; None: the add-on's), the slots every vertex evaluates ``shared_slots`` (see
    :func:`lbc_addon.node_group.build_node_group`; None: the add-on's choice), its tree changed as ``tree`` says (see
    :func:`rebuild_tree`, or "sorted": each vertex's slots ordered by weight, largest first; None: as built)."""
    obj = copy_object(bound, name)
    index, weight = storage.read(obj.data)
    cage_rest = cage_rest_local(cage, obj)
    if thinning is not None:
        rows = np.repeat(np.arange(len(index)), index.shape[1])
        weights = sp.csr_matrix((weight.astype(float).ravel(), (rows, index.ravel())),
                                shape=(len(index), len(cage_rest)))
        weights.eliminate_zeros()
        index, weight = storage.slot_arrays(thin_weights(weights, cage_rest, weights @ cage_rest, *thinning),
                                            np.arange(len(cage_rest)))
    if tree == "sorted":  # each vertex's largest weights first (the padding still last)
        order = np.argsort(-weight, axis=1, kind="stable")
        index, weight = np.take_along_axis(index, order, axis=1), np.take_along_axis(weight, order, axis=1)
    storage.remove(obj.data)
    storage.write(obj.data, index, weight, storage.rest_offsets(index, weight, cage_rest))
    deformer.attach(obj, cage, index.shape[1], len(cage.data.vertices), len(obj.data.vertices),
                    node_group.shared_slot_count(weight) if shared_slots is None else shared_slots)
    if sum_form is not None:
        rebuild_sum(obj, sum_form)
    if tree not in (None, "sorted"):
        rebuild_tree(obj, tree)
    return obj


def cage_triplets(index, weight, cage_vertex_count):
    """The cage's vertices in groups of three that the mesh's vertices use together: greedily, the two used together
    by the most vertices, then the vertex used with both by the most; a last group of one or two is padded with its
    first member (weight 0 there).

    Returns
    -------
    members : (T, 3) int array
        Each group's cage vertices.
    """
    rows = np.repeat(np.arange(len(index)), index.shape[1])
    used = (weight > 0).ravel()
    usage = sp.csr_matrix((np.ones(used.sum()), (rows[used], index.ravel()[used])),
                          shape=(len(index), cage_vertex_count))
    together = (usage.T @ usage).toarray()
    np.fill_diagonal(together, -1)
    free, members = list(range(cage_vertex_count)), []
    while free:
        shared = together[np.ix_(free, free)]
        first, second = np.unravel_index(np.argmax(shared), shared.shape)
        group = [free[first], free[second]] if len(free) > 1 else [free[0]]
        rest = [vertex for vertex in free if vertex not in group]
        if rest and len(group) == 2:
            group.append(rest[int(np.argmax(together[np.ix_(rest, group)].min(axis=1)))])
        members.append(group + [group[0]] * (3 - len(group)))
        free = [vertex for vertex in free if vertex not in group]
    return np.array(members)


def triplet_slots(index, weight, members):
    """Each vertex's weights grouped by the cage triplets ``members`` (T, 3): slots of (triplet, weights of its three
    vertices), the padding (triplet 0, weights 0) last. Returns (m, S) int32 and (m, S, 3) float32."""
    triplet_of = np.empty(members.max() + 1, dtype=np.int64)
    place_of = np.empty_like(triplet_of)
    for triplet, group in enumerate(members):
        for place, vertex in reversed(list(enumerate(group))):  # a padded repeat keeps the first place
            triplet_of[vertex], place_of[vertex] = triplet, place
    used = weight > 0
    label = np.where(used, triplet_of[index], len(members))  # unused sorts last
    order = np.argsort(label, axis=1, kind="stable")
    ordered = np.take_along_axis(label, order, axis=1)
    new = np.ones_like(ordered, dtype=bool)
    new[:, 1:] = ordered[:, 1:] != ordered[:, :-1]
    slot_sorted = np.cumsum(new, axis=1) - 1
    slot = np.empty_like(slot_sorted)
    np.put_along_axis(slot, order, slot_sorted, axis=1)
    count = int((np.where(used, slot, -1).max(axis=1) + 1).max())
    tri_index = np.zeros((len(index), count), dtype=np.int32)
    tri_weight = np.zeros((len(index), count, 3), dtype=np.float32)
    rows, columns = np.nonzero(used)
    tri_index[rows, slot[rows, columns]] = triplet_of[index[rows, columns]]
    np.add.at(tri_weight, (rows, slot[rows, columns], place_of[index[rows, columns]]), weight[rows, columns])
    return tri_index, tri_weight


def triplet_variant(bound, cage, name):
    """The default binding's weights grouped by cage triplets (:func:`cage_triplets`): per slot one gathered 4×4
    matrix whose first three columns are the triplet's cage positions, times the slot's weight vector (Transform
    Direction), so a slot carries up to three weights; the matrices are built once per frame on a point cloud of T
    points. Two tiers as the add-on's (the second on the vertices with a weight in slot B)."""
    obj = copy_object(bound, name)
    index, weight = storage.read(obj.data)
    members = cage_triplets(index, weight, len(cage.data.vertices))
    tri_index, tri_weight = triplet_slots(index, weight, members)
    totals = tri_weight.sum(axis=2)
    for slot in range(tri_index.shape[1]):
        obj.data.attributes.new(f".bench_triplet_{slot}", "INT", "POINT").data.foreach_set("value", tri_index[:, slot])
        obj.data.attributes.new(f".bench_triplet_weights_{slot}", "FLOAT_VECTOR", "POINT").data.foreach_set(
            "vector", tri_weight[:, slot].ravel())
        obj.data.attributes[storage.weight_name(slot)].data.foreach_set("value", totals[:, slot])  # the tail's test
    shared = node_group.shared_slot_count(totals)
    print(f"  triplets: {len(members)} of the cage's {len(cage.data.vertices)} vertices; slots {tri_index.shape[1]} "
          f"(every vertex {shared}), {np.count_nonzero(totals, axis=1).mean():.2f} per vertex on average")
    clouds = {}

    def triplet_samples(group, cage_geometry, position, slots):
        nodes, links = group.nodes, group.links
        if group.name not in clouds:
            points = nodes.new("GeometryNodePoints")
            node_group._input(points, "Count").default_value = len(members)
            point_index = nodes.new("GeometryNodeInputIndex")
            combine = nodes.new("FunctionNodeCombineMatrix")
            for column in range(3):
                switch = nodes.new("GeometryNodeIndexSwitch")
                switch.data_type = "INT"
                while len(switch.index_switch_items) < len(members):
                    switch.index_switch_items.new()
                links.new(point_index.outputs["Index"], node_group._input(switch, "Index"))
                for triplet in range(len(members)):
                    switch.inputs[triplet + 1].default_value = int(members[triplet, column])
                sample = nodes.new("GeometryNodeSampleIndex")
                sample.data_type, sample.domain = "FLOAT_VECTOR", "POINT"
                links.new(cage_geometry, node_group._input(sample, "Geometry"))
                links.new(position.outputs["Position"], node_group._input(sample, "Value"))
                links.new(switch.outputs["Output"], node_group._input(sample, "Index"))
                separate = nodes.new("ShaderNodeSeparateXYZ")
                links.new(sample.outputs["Value"], node_group._input(separate, "Vector"))
                for row, axis in enumerate("XYZ"):
                    links.new(separate.outputs[axis], node_group._input(combine, f"Column {column + 1} Row {row + 1}"))
            store = nodes.new("GeometryNodeStoreNamedAttribute")
            store.data_type, store.domain = "FLOAT4X4", "POINT"
            links.new(points.outputs["Points"], node_group._input(store, "Geometry"))
            node_group._input(store, "Name").default_value = ".bench_matrix"
            links.new(combine.outputs["Matrix"], node_group._input(store, "Value"))
            read = node_group._named_attribute(nodes, "FLOAT4X4", ".bench_matrix", (0, 0))
            clouds[group.name] = store.outputs["Geometry"], read.outputs["Attribute"]
        cloud, matrix = clouds[group.name]
        terms = []
        for slot in slots:
            triplet = node_group._named_attribute(nodes, "INT", f".bench_triplet_{slot}", (0, 0))
            weights = node_group._named_attribute(nodes, "FLOAT_VECTOR", f".bench_triplet_weights_{slot}", (0, 0))
            sample = nodes.new("GeometryNodeSampleIndex")
            sample.data_type, sample.domain = "FLOAT4X4", "POINT"
            links.new(cloud, node_group._input(sample, "Geometry"))
            links.new(matrix, node_group._input(sample, "Value"))
            links.new(triplet.outputs["Attribute"], node_group._input(sample, "Index"))
            product = nodes.new("FunctionNodeTransformDirection")
            links.new(weights.outputs["Attribute"], node_group._input(product, "Direction"))
            links.new(sample.outputs["Value"], node_group._input(product, "Transform"))
            terms.append(product.outputs["Direction"])
        return terms

    original = node_group._weighted_samples
    node_group._weighted_samples = triplet_samples
    try:
        deformer.attach(obj, cage, tri_index.shape[1], len(cage.data.vertices), len(obj.data.vertices), shared)
    finally:
        node_group._weighted_samples = original
    return obj


def rebuild_tree(obj, form):
    """Change the deformer's tree, to measure a lever.

    "direct": Set Position's Position fed Σ w_k c_k itself, no offset (no rest attribute read, no subtraction; on
    the plain path only, Strength 1 and no vertex group, and not exact where the rest differs from the vertex:
    a bound on the lever's gain). "pairs": each slot's (index, weight) in one 2D vector attribute, one Named
    Attribute read and a Separate XYZ instead of two reads. "points": the cage sampled as a point cloud (Mesh to
    Points, once) instead of the Object Info mesh. "displacement": every slot samples the cage's displacement
    d = c - c_rest, stored once per frame on the cage's points (its rest positions read from an attribute on the
    mesh's first vertices), so Set Position's offset is Σ w_k d_k: no rest read or subtraction per vertex, the same
    deformation. "compact-tail": the tail's slots (those only some vertices use) summed on the mesh's first T
    vertices, a contiguous range, from compact copies of the T tail vertices' slots stored there, then gathered back
    by each vertex's stored rank (none: out of range, a zero vector) instead of evaluated on the scattered tail
    vertices.
    """
    group = obj.modifiers[0].node_group
    nodes, links = group.nodes, group.links
    samples = [n for n in nodes if n.bl_idname == "GeometryNodeSampleIndex"]
    if form == "direct":
        subtract = next(n for n in nodes if n.bl_idname == "ShaderNodeVectorMath" and n.operation == "SUBTRACT")
        total = node_group._inputs(subtract, "Vector")[0].links[0].from_socket
        set_position = next(n for n in nodes if n.bl_idname == "GeometryNodeSetPosition"
                            and node_group._input(n, "Geometry").links[0].from_node.bl_idname == "NodeGroupInput")
        links.remove(node_group._input(set_position, "Offset").links[0])
        links.new(total, node_group._input(set_position, "Position"))
    elif form == "pairs":
        index, weight = storage.read(obj.data)
        for slot in range(index.shape[1]):
            attribute = obj.data.attributes.new(f".bench_pair_{slot}", "FLOAT2", "POINT")
            attribute.data.foreach_set("vector", np.column_stack([index[:, slot], weight[:, slot]]).astype(
                np.float32).ravel())
        reads = {node_group._input(n, "Name").default_value: n for n in nodes
                 if n.bl_idname == "GeometryNodeInputNamedAttribute" and n.data_type in ("INT", "FLOAT")}
        for slot in range(index.shape[1]):
            index_read, weight_read = reads[storage.index_name(slot)], reads[storage.weight_name(slot)]
            pair = node_group._named_attribute(nodes, "FLOAT_VECTOR", f".bench_pair_{slot}", index_read.location)
            separate = nodes.new("ShaderNodeSeparateXYZ")
            links.new(pair.outputs["Attribute"], node_group._input(separate, "Vector"))
            for read, output in ((index_read, "X"), (weight_read, "Y")):
                for link in list(read.outputs["Attribute"].links):
                    to_socket = link.to_socket
                    if to_socket.node.bl_idname == "FunctionNodeCompare":  # the tail's selection keeps its read
                        continue
                    links.remove(link)
                    links.new(separate.outputs[output], to_socket)
    elif form == "points":
        cage_geometry = node_group._input(samples[0], "Geometry").links[0].from_socket
        points = nodes.new("GeometryNodeMeshToPoints")
        points.mode = "VERTICES"
        links.new(cage_geometry, node_group._input(points, "Mesh"))
        for sample in samples:
            links.new(points.outputs["Points"], node_group._input(sample, "Geometry"))
    elif form == "displacement":
        cage = deformer.inputs(obj.modifiers[0])["Cage"]
        rest = cage_rest_local(cage, obj)
        attribute = obj.data.attributes.new(".bench_cage_rest", "FLOAT_VECTOR", "POINT")
        values = np.zeros((len(obj.data.vertices), 3), dtype=np.float32)
        values[:len(rest)] = rest
        attribute.data.foreach_set("vector", values.ravel())
        group_in = next(n for n in nodes if n.bl_idname == "NodeGroupInput")
        cage_geometry = node_group._input(samples[0], "Geometry").links[0].from_socket
        rest_read = node_group._named_attribute(nodes, "FLOAT_VECTOR", ".bench_cage_rest", (0, 600))
        rest_sample = nodes.new("GeometryNodeSampleIndex")
        rest_sample.data_type, rest_sample.domain = "FLOAT_VECTOR", "POINT"
        links.new(group_in.outputs["Geometry"], node_group._input(rest_sample, "Geometry"))
        links.new(rest_read.outputs["Attribute"], node_group._input(rest_sample, "Value"))
        links.new(nodes.new("GeometryNodeInputIndex").outputs["Index"], node_group._input(rest_sample, "Index"))
        displacement = node_group._vector_math(nodes, "SUBTRACT", (0, 700))
        position = nodes.new("GeometryNodeInputPosition").outputs["Position"]
        links.new(position, node_group._inputs(displacement, "Vector")[0])
        links.new(rest_sample.outputs["Value"], node_group._inputs(displacement, "Vector")[1])
        store = nodes.new("GeometryNodeStoreNamedAttribute")
        store.data_type, store.domain = "FLOAT_VECTOR", "POINT"
        node_group._input(store, "Name").default_value = ".bench_displacement"
        links.new(cage_geometry, node_group._input(store, "Geometry"))
        links.new(displacement.outputs["Vector"], node_group._input(store, "Value"))
        displacement_read = node_group._named_attribute(nodes, "FLOAT_VECTOR", ".bench_displacement", (0, 800))
        for sample in samples:
            links.new(store.outputs["Geometry"], node_group._input(sample, "Geometry"))
            links.new(displacement_read.outputs["Attribute"], node_group._input(sample, "Value"))
        subtract = next(n for n in nodes if n.bl_idname == "ShaderNodeVectorMath" and n.operation == "SUBTRACT"
                        and n is not displacement)
        total = node_group._inputs(subtract, "Vector")[0].links[0].from_socket
        for link in list(subtract.outputs["Vector"].links):
            to_socket = link.to_socket
            links.remove(link)
            links.new(total, to_socket)
        nodes.remove(subtract)
    elif form == "compact-tail":
        compact_tail(obj, group)
    else:
        raise ValueError(f"unknown tree form {form!r}")


def compact_tail(obj, group):
    """The tail of :func:`rebuild_tree`'s "compact-tail"."""
    nodes, links = group.nodes, group.links
    index, weight = storage.read(obj.data)
    set_tail = next(n for n in nodes if n.bl_idname == "GeometryNodeSetPosition"
                    and node_group._input(n, "Selection").is_linked)
    first = node_group.shared_slot_count(weight)
    rows = np.flatnonzero(weight[:, first] != 0)
    count = len(obj.data.vertices)
    rank = np.full(count, count, dtype=np.int32)  # past the end: Sample Index gives zero
    rank[rows] = np.arange(len(rows), dtype=np.int32)
    obj.data.attributes.new(".bench_tail_rank", "INT", "POINT").data.foreach_set("value", rank)
    terms = []
    for slot in range(first, index.shape[1]):
        compact_index = np.zeros(count, dtype=np.int32)
        compact_weight = np.zeros(count, dtype=np.float32)
        compact_index[:len(rows)], compact_weight[:len(rows)] = index[rows, slot], weight[rows, slot]
        obj.data.attributes.new(f".bench_tail_index_{slot}", "INT", "POINT").data.foreach_set("value", compact_index)
        obj.data.attributes.new(f".bench_tail_weight_{slot}", "FLOAT", "POINT").data.foreach_set(
            "value", compact_weight)
        # Each slot of the old tail: its Sample Index of the cage, re-fed with the compact index and weight.
        old_sample = next(n for n in nodes if n.bl_idname == "GeometryNodeSampleIndex"
                          and node_group._input(n, "Index").links[0].from_node.bl_idname
                          == "GeometryNodeInputNamedAttribute"
                          and node_group._input(node_group._input(n, "Index").links[0].from_node, "Name").default_value
                          == storage.index_name(slot))
        sample = nodes.new("GeometryNodeSampleIndex")
        sample.data_type, sample.domain = "FLOAT_VECTOR", "POINT"
        for name in ("Geometry", "Value"):
            links.new(node_group._input(old_sample, name).links[0].from_socket, node_group._input(sample, name))
        compact = node_group._named_attribute(nodes, "INT", f".bench_tail_index_{slot}", (0, 0))
        links.new(compact.outputs["Attribute"], node_group._input(sample, "Index"))
        scaled = node_group._vector_math(nodes, "SCALE", (0, 0))
        links.new(sample.outputs["Value"], node_group._input(scaled, "Vector"))
        links.new(node_group._named_attribute(nodes, "FLOAT", f".bench_tail_weight_{slot}", (0, 0)).outputs["Attribute"],
                  node_group._input(scaled, "Scale"))
        terms.append(scaled.outputs["Vector"])
    total = node_group.pairwise_sum(group, terms, 0)
    in_range = node_group._compare(nodes, "INT", "LESS_THAN", (0, 0))
    links.new(nodes.new("GeometryNodeInputIndex").outputs["Index"], node_group._input(in_range, "A"))
    node_group._input(in_range, "B").default_value = len(rows)
    store = nodes.new("GeometryNodeStoreNamedAttribute")
    store.data_type, store.domain = "FLOAT_VECTOR", "POINT"
    node_group._input(store, "Name").default_value = ".bench_tail_sum"
    links.new(node_group._input(set_tail, "Geometry").links[0].from_socket, node_group._input(store, "Geometry"))
    links.new(in_range.outputs["Result"], node_group._input(store, "Selection"))
    links.new(total, node_group._input(store, "Value"))
    gather = nodes.new("GeometryNodeSampleIndex")
    gather.data_type, gather.domain = "FLOAT_VECTOR", "POINT"
    links.new(store.outputs["Geometry"], node_group._input(gather, "Geometry"))
    links.new(node_group._named_attribute(nodes, "FLOAT_VECTOR", ".bench_tail_sum", (0, 0)).outputs["Attribute"],
              node_group._input(gather, "Value"))
    links.new(node_group._named_attribute(nodes, "INT", ".bench_tail_rank", (0, 0)).outputs["Attribute"],
              node_group._input(gather, "Index"))
    # The old tail sum feeds the Strength / mask product and its switch: the gathered sum takes its place there.
    offset_switch = node_group._input(set_tail, "Offset").links[0].from_node
    old_sum = node_group._input(offset_switch, "True").links[0].from_socket
    for link in list(old_sum.links):
        to_socket = link.to_socket
        links.remove(link)
        links.new(gather.outputs["Value"], to_socket)
    links.new(store.outputs["Geometry"], node_group._input(set_tail, "Geometry"))
    links.remove(node_group._input(set_tail, "Selection").links[0])


def rebuild_sum(obj, form):
    """Rebuild the deformer's Σ w_k c_k in another shape, to measure the node tree's shape as a lever.

    The add-on's: per slot a Scale (sample × weight), summed pairwise in a balanced tree of Adds
    (:func:`lbc_addon.node_group.pairwise_sum`). "chain": the Scales added one after the other to a running total.
    "fma": per slot one Multiply Add (sample × weight + running total), the weight converted to a vector on the
    way. "fma-vector": the same with each weight stored as a vector attribute (w, w, w), three times its memory, so
    that nothing is converted.
    """
    group = obj.modifiers[0].node_group
    nodes, links = group.nodes, group.links
    samples = sorted((n for n in nodes if n.bl_idname == "GeometryNodeSampleIndex"), key=lambda n: -n.location.y)
    weights = {node_group._input(n, "Name").default_value: n for n in nodes
               if n.bl_idname == "GeometryNodeInputNamedAttribute" and n.data_type == "FLOAT"}
    subtract = next(n for n in nodes if n.bl_idname == "ShaderNodeVectorMath" and n.operation == "SUBTRACT")
    for node in list(nodes):  # the add-on's sum: every vector Add, and the Scales of the samples
        if node.bl_idname == "ShaderNodeVectorMath" and (node.operation == "ADD" or node.operation == "SCALE" and any(
                link.from_node.bl_idname == "GeometryNodeSampleIndex" for link in node.inputs[0].links)):
            nodes.remove(node)
    if form == "fma-vector":
        _, weight_values = storage.read(obj.data)
        for slot in range(weight_values.shape[1]):
            attribute = obj.data.attributes.new(f".bench_weight3_{slot}", "FLOAT_VECTOR", "POINT")
            attribute.data.foreach_set("vector", np.repeat(weight_values[:, slot], 3))
    total = None
    for slot, sample in enumerate(samples):
        if form == "fma-vector":
            weight = node_group._named_attribute(nodes, "FLOAT_VECTOR", f".bench_weight3_{slot}", (0, 0))
        else:
            weight = weights[storage.weight_name(slot)]
        if form.startswith("fma"):
            node = node_group._vector_math(nodes, "MULTIPLY_ADD", (0, 0))
            vectors = node_group._inputs(node, "Vector")
            links.new(sample.outputs["Value"], vectors[0])
            links.new(weight.outputs["Attribute"], vectors[1])
            if total is None:
                vectors[2].default_value = (0.0, 0.0, 0.0)
            else:
                links.new(total, vectors[2])
            total = node.outputs["Vector"]
            continue
        node = node_group._vector_math(nodes, "SCALE", (0, 0))
        links.new(sample.outputs["Value"], node_group._input(node, "Vector"))
        links.new(weight.outputs["Attribute"], node_group._input(node, "Scale"))
        if total is None:
            total = node.outputs["Vector"]
        else:  # "chain"
            add = node_group._vector_math(nodes, "ADD", (0, 0))
            links.new(total, node_group._inputs(add, "Vector")[0])
            links.new(node.outputs["Vector"], node_group._inputs(add, "Vector")[1])
            total = add.outputs["Vector"]
    links.new(total, node_group._inputs(subtract, "Vector")[0])


def cage_rest_local(cage, obj):
    matrix = np.array(obj.matrix_world.inverted() @ cage.matrix_world)
    return positions(cage.data) @ matrix[:3, :3].T + matrix[:3, 3]


def mesh_deform_variant(mesh, cage, name, precision):
    obj = copy_object(mesh, name)
    bpy.context.scene.collection.objects.link(obj)
    modifier = obj.modifiers.new("Mesh Deform", "MESH_DEFORM")
    modifier.object = cage
    modifier.precision = precision
    start = time.perf_counter()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.meshdeform_bind(modifier=modifier.name)
    print(f"  Mesh Deform bound in {time.perf_counter() - start:.1f} s (precision {precision})")
    bpy.context.scene.collection.objects.unlink(obj)
    return obj


def deformation_error(obj, reference, cage, rest, scale):
    """Largest distance between ``obj``'s and ``reference``'s evaluated vertices over three poses, / ``scale``."""
    worst = 0.0
    for phase in (0.7, 2.1, 4.0):
        set_cage(cage, pose(rest, phase))
        worst = max(worst, float(np.abs(evaluated(obj) - evaluated(reference)).max()))
    set_cage(cage, rest)
    return worst / scale


def evaluated(obj):
    """``obj``'s deformed vertices, linking it into the scene for the time it takes if it is not."""
    collection = bpy.context.scene.collection
    linked = obj.name not in collection.objects
    if linked:
        collection.objects.link(obj)
    try:
        return evaluated_positions(obj)
    finally:
        if linked:
            collection.objects.unlink(obj)


def measure(variants, cage, rest, rounds, without_handler=(), playback=False):
    """Milliseconds per frame, per variant: {name: (wall, cpu) arrays (rounds,)}.

    Edit (``playback`` False): the depsgraph update after a cage edit, the add-on's depsgraph handler included;
    variants named in ``without_handler`` are measured with the add-on's handlers unregistered. Playback: the cage
    animated (:func:`animate`), the time of ``scene.frame_set`` to the next frame, as an artist's playback or render
    (Blender calls no depsgraph update handler on a frame change).

    Wall time is what the artist waits; the process's CPU time (every thread's) is the work done, which a machine
    shared with other jobs inflates less.
    """
    scene = bpy.context.scene
    times = {name: [] for name in variants}
    names = list(variants)
    if playback:
        animate(cage, rest, 2 * rounds + 2)
    for number in range(rounds):
        shift = number % len(names)
        for name in names[shift:] + names[:shift]:
            obj = variants[name]
            scene.collection.objects.link(obj)
            if name in without_handler:
                handlers.unregister()
            # Untimed: relations rebuilt after linking; then the same timed change for every variant of the round.
            if playback:
                scene.frame_set(2 * number + 1)
            else:
                set_cage(cage, pose(rest, 0.37 * number))
                bpy.context.evaluated_depsgraph_get()
                set_cage(cage, pose(rest, 0.37 * number + 0.2))
            start, cpu = time.perf_counter(), time.process_time()
            if playback:
                scene.frame_set(2 * number + 2)
            else:
                bpy.context.evaluated_depsgraph_get()
            times[name].append((1000 * (time.perf_counter() - start), 1000 * (time.process_time() - cpu)))
            if name in without_handler:
                handlers.register()
            scene.collection.objects.unlink(obj)
    if playback:
        cage.shape_key_clear()
        cage.data.update()
    set_cage(cage, rest)
    return {name: np.array(values) for name, values in times.items()}


def animate(cage, rest, frames):
    """Animate the cage by two shape keys, the twist and the bulge of :func:`pose`, their values keyframed on every
    frame from 1 to ``frames`` (0.37 radians of :func:`pose`'s phase per frame)."""
    cage.shape_key_add(name="Basis", from_mix=False)
    keys = []
    for name, phase in (("Twist", np.pi / 2), ("Bulge", 0.0)):
        key = cage.shape_key_add(name=name, from_mix=False)
        key.slider_min = -1.0
        key.data.foreach_set("co", np.asarray(pose(rest, phase), dtype=np.float32).ravel())
        keys.append(key)
    for frame in range(1, frames + 1):
        keys[0].value, keys[1].value = np.sin(0.37 * frame), np.cos(0.37 * frame)
        for key in keys:
            key.keyframe_insert("value", frame=frame)


def smoothness_variants(mesh, cage, values):
    """Copies of the mesh bound with the add-on's defaults but Smoothness, one per value: {name: object}."""
    variants = {}
    for value in values:
        obj = copy_object(mesh, f"smoothness {value:g}")
        storage.remove(obj.data)
        bpy.context.scene.collection.objects.link(obj)
        start = time.perf_counter()
        summary = api.bind(obj, cage, smoothness=value)
        print(f"  LBC bound in {time.perf_counter() - start:.1f} s at Smoothness {value:g}: K = {summary.slots}, "
              f"{summary.mean_influences:.1f} influences per vertex on average")
        bpy.context.scene.collection.objects.unlink(obj)
        variants[f"LBC smoothness {value:g} K={summary.slots}"] = obj
    return variants


def run_scene(name, thinnings, sum_forms, rounds, precision, reference_cells, handler_off=False, shared=(),
              trees=(), modes=("edit", "playback"), smoothness=()):
    mesh, cage = SCENES[name]()
    rest = positions(cage.data)
    print(f"\n{name}: {len(mesh.data.vertices)} vertices, cage {len(rest)} vertices")
    default = copy_object(mesh, "default")
    bpy.context.scene.collection.objects.link(default)
    start = time.perf_counter()
    summary = api.bind(mesh, cage, thinning=EVERY_WEIGHT)  # every weight: the other variants are thinned from it
    full = summary.slots
    print(f"  LBC bound in {time.perf_counter() - start:.1f} s with every weight: K = {full}, "
          f"{summary.mean_influences:.1f} influences per vertex on average, {summary.outside} outside")
    start = time.perf_counter()
    summary = api.bind(default, cage)
    print(f"  LBC bound in {time.perf_counter() - start:.1f} s with the add-on's defaults: K = {summary.slots}, "
          f"{summary.mean_influences:.1f} influences per vertex on average")
    scale = float(np.linalg.norm(np.ptp(positions(mesh.data), axis=0)))
    for obj in (mesh, default):
        bpy.context.scene.collection.objects.unlink(obj)
    others = smoothness_variants(mesh, cage, smoothness)
    variants = {"no deformer": copy_object(mesh, "plain")}
    variants["Mesh Deform"] = mesh_deform_variant(mesh, cage, "meshdeform", precision)
    variants[f"LBC every weight K={full}"] = mesh
    variants[f"LBC default K={summary.slots}"] = default
    variants.update(others)

    def compare(key, reference, what):
        error = deformation_error(variants[key], reference, cage, rest, scale)
        print(f"  {key}: largest difference to {what} over three poses {error:.2e} of the mesh's diagonal")

    compare(f"LBC default K={summary.slots}", mesh, "every weight")
    if reference_cells:
        # The yardstick for thinning's error: how far the binding itself is from one on twice as fine a domain mesh.
        variants[f"LBC {reference_cells} cells"] = fine = copy_object(mesh, "fine")
        bpy.context.scene.collection.objects.link(fine)
        storage.remove(fine.data)
        start = time.perf_counter()
        api.bind(fine, cage, cells=reference_cells, thinning=EVERY_WEIGHT)
        print(f"  LBC at {reference_cells} cells bound in {time.perf_counter() - start:.1f} s")
        bpy.context.scene.collection.objects.unlink(fine)
        compare(f"LBC {reference_cells} cells", mesh, "the default resolution's")
        del variants[f"LBC {reference_cells} cells"]
    for floor, cap in thinnings:
        key = f"LBC thin {floor:g}:{cap}"
        variants[key] = lbc_variant(mesh, cage, key, (floor, cap))
        compare(key, mesh, "every weight")
        print(f"    (K = {storage.slot_count(variants[key].data)} after thinning)")
    for form in sum_forms:  # at every weight, and as bound by default
        variants[f"LBC every weight {form}"] = lbc_variant(mesh, cage, form, None, form)
        compare(f"LBC every weight {form}", mesh, "the add-on's tree")
        variants[f"LBC default {form}"] = lbc_variant(default, cage, form, None, form)
    for slots in shared:  # the default's weights, another split of the slots (0: every slot for every vertex)
        key = f"LBC default shared {slots or summary.slots}"
        variants[key] = lbc_variant(default, cage, key, shared_slots=slots or summary.slots)
        compare(key, default, "the default's")
    for form in trees:
        key = f"LBC default {form}"
        variants[key] = (triplet_variant(default, cage, key) if form == "triplets"
                         else lbc_variant(default, cage, key, tree=form))
        compare(key, default, "the default's")
    without_handler = ()
    if handler_off:  # the default binding again, the add-on's check of it after each cage edit left out
        without_handler = (f"LBC default K={summary.slots} no handler",)
        variants[without_handler[0]] = default
    for mode in modes:
        playback = mode == "playback"
        load = os.getloadavg()[0]
        times = measure(variants, cage, rest, rounds, () if playback else without_handler, playback)
        what = "frame_set, the cage animated by shape keys" if playback else "the update after a cage edit"
        print(f"  {mode}: {what}; {rounds} interleaved frames each, load average {load:.2f} before, "
              f"{os.getloadavg()[0]:.2f} after")
        print(f"  {'variant':36}{'wall ms: median':>16}{'quartiles':>14}{'CPU ms: median':>16}{'quartiles':>14}")
        for variant, values in times.items():
            if playback and variant in without_handler:
                continue  # the same as the default in playback: no handler runs
            columns = ""
            for kind in (0, 1):
                low, mid, high = np.percentile(values[:, kind], [25, 50, 75])
                columns += f"{mid:16.2f}{f'{low:.2f}-{high:.2f}':>14}"
            print(f"  {variant:36}{columns}")


def thinning(text):
    """(floor, cap) from "floor:cap"."""
    floor, cap = text.split(":")
    return float(floor), int(cap)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=31, help="timed frames per variant (interleaved rounds)")
    parser.add_argument("--scenes", default="suzanne,gargoyle")
    parser.add_argument("--thin", default="",
                        help="comma-separated floor:cap thinnings of every weight to measure besides the "
                        "default (see lbc_core.evaluate.thinning.thin_weights), e.g. 0.002:0,0.005:12")
    parser.add_argument("--sums", default="",
                        help="comma-separated other shapes of the weighted sum: chain,fma,fma-vector")
    parser.add_argument("--reference-cells", type=int, default=0,
                        help="also bind at this resolution and print how far the default binding is from it")
    parser.add_argument("--precision", type=int, default=5, help="Mesh Deform precision")
    parser.add_argument("--handler-off", action="store_true",
                        help="also measure the default binding with the add-on's depsgraph handler unregistered")
    parser.add_argument("--shared", default="",
                        help="comma-separated slot counts every vertex evaluates, the rest only where used, for "
                        "copies of the default binding (0: every slot for every vertex), e.g. 0,11,12")
    parser.add_argument("--trees", default="",
                        help="comma-separated changes of the default's tree: direct,pairs,points,sorted,triplets")
    parser.add_argument("--smoothness", default="",
                        help="comma-separated Smoothness values to bind copies with besides the default, e.g. 0,1")
    parser.add_argument("--modes", default="edit,playback",
                        help="what a frame is: edit (the update after a cage edit, the add-on's handler included), "
                        "playback (frame_set, the cage animated)")
    args = parser.parse_args(argv)
    register_addon()
    thinnings = [thinning(value) for value in args.thin.split(",") if value]
    for name in args.scenes.split(","):
        run_scene(name, thinnings, [form for form in args.sums.split(",") if form], args.frames, args.precision,
                  args.reference_cells, args.handler_off, [int(value) for value in args.shared.split(",") if value],
                  [form for form in args.trees.split(",") if form], args.modes.split(","),
                  [float(value) for value in args.smoothness.split(",") if value])


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # bpy 4.5.4 can deadlock in its teardown at exit (see tests/conftest.py)
