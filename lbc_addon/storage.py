"""The binding's cache in the mesh data: hidden point attributes saved with the .blend.

Each mesh vertex keeps K (index, weight) slots, K being the largest number of cage vertices that influence one mesh
vertex; rows with fewer influences are padded with weight 0. Beside them ``.lbc_rest`` holds Σ w_k c_k at bind time
(c_k the cage's rest positions), so the deformer adds the displacement Σ w_k c_k − rest to the vertex's own position
and the rest pose is the mesh exactly, not its reconstruction from the weights. Names start with a dot: Blender hides
such attributes from the attribute lists and keeps them through deform modifiers.
"""

import numpy as np

INDEX_PREFIX = ".lbc_index_"
WEIGHT_PREFIX = ".lbc_weight_"
REST_NAME = ".lbc_rest"


def index_name(slot):
    """Name of the attribute holding each vertex's ``slot``-th cage vertex index."""
    return f"{INDEX_PREFIX}{slot}"


def weight_name(slot):
    """Name of the attribute holding each vertex's ``slot``-th weight."""
    return f"{WEIGHT_PREFIX}{slot}"


def slot_arrays(weights, column_vertex):
    """Sparse weights to K padded slots, each vertex's weights first and its padding (weight 0) last.

    The deformer relies on the padding coming last: it evaluates the last slots only on the vertices whose first of
    them holds a weight (see :func:`node_group.build_node_group`).

    Parameters
    ----------
    weights : scipy.sparse matrix (m, n)
    column_vertex : (n,) int array
        The cage vertex each column stands for.

    Returns
    -------
    index (m, K) int32, weight (m, K) float32
    """
    weights = weights.tocsr()
    weights.sort_indices()
    counts = np.diff(weights.indptr)
    slots = max(int(counts.max()) if len(counts) else 0, 1)
    rows = np.repeat(np.arange(weights.shape[0]), counts)
    position = np.arange(weights.nnz) - np.repeat(weights.indptr[:-1], counts)
    index = np.zeros((weights.shape[0], slots), dtype=np.int32)
    weight = np.zeros((weights.shape[0], slots), dtype=np.float32)
    index[rows, position] = np.asarray(column_vertex)[weights.indices]
    weight[rows, position] = weights.data
    return index, weight


def rest_offsets(index, weight, cage_positions):
    """Σ_k w_k c_k per vertex, (m, 3), from the float32 weights and cage positions (n, 3) the deformer multiplies:
    at the cage's rest, the rest each vertex's weights reproduce."""
    positions = np.asarray(cage_positions, dtype=np.float32).astype(np.float64)
    weight = weight.astype(np.float64)
    # One coordinate at a time: gathering (m, K, 3) positions at once costs twice as much.
    return np.stack([np.einsum("mk,mk->m", weight, column[index]) for column in positions.T], axis=1)


def write(mesh, index, weight, rest):
    """Store the slots and rest offsets on a ``bpy.types.Mesh`` (one value per vertex)."""
    for slot in range(index.shape[1]):
        attribute = mesh.attributes.new(index_name(slot), "INT", "POINT")
        attribute.data.foreach_set("value", np.ascontiguousarray(index[:, slot]))
        attribute = mesh.attributes.new(weight_name(slot), "FLOAT", "POINT")
        attribute.data.foreach_set("value", np.ascontiguousarray(weight[:, slot]))
    attribute = mesh.attributes.new(REST_NAME, "FLOAT_VECTOR", "POINT")
    attribute.data.foreach_set("vector", np.asarray(rest, dtype=np.float32).ravel())


def copy_attributes(mesh, names):
    """The values of the mesh's attributes called ``names`` (those that exist), for :func:`restore_attributes`.

    Returns
    -------
    list of (name, domain, data_type, values (length × width,) array)
    """
    saved = []
    for name in names:
        attribute = mesh.attributes.get(name)
        if attribute is None:
            continue
        field, dtype = _FIELDS[attribute.data_type]
        values = np.empty(len(attribute.data) * _WIDTHS.get(attribute.data_type, 1), dtype=dtype)
        attribute.data.foreach_get(field, values)
        saved.append((name, attribute.domain, attribute.data_type, values))
    return saved


def restore_attributes(mesh, saved, names):
    """Remove the attributes called ``names``, then recreate those of ``saved`` (:func:`copy_attributes`)."""
    for name in names:
        attribute = mesh.attributes.get(name)
        if attribute is not None:
            mesh.attributes.remove(attribute)
    for name, domain, data_type, values in saved:
        attribute = mesh.attributes.new(name, data_type, domain)
        attribute.data.foreach_set(_FIELDS[data_type][0], values)


# The attribute types this add-on writes (its own and the influence colors): foreach field and dtype, width.
_FIELDS = {"INT": ("value", np.int32), "FLOAT": ("value", np.float32), "FLOAT_VECTOR": ("vector", np.float32),
           "FLOAT_COLOR": ("color", np.float32)}
_WIDTHS = {"FLOAT_VECTOR": 3, "FLOAT_COLOR": 4}


def binding_names(mesh):
    """The names of every attribute this add-on's binding wrote on the mesh."""
    return [a.name for a in mesh.attributes if a.name.startswith((INDEX_PREFIX, WEIGHT_PREFIX)) or a.name == REST_NAME]


def slot_count(mesh):
    """K, the number of slots stored on the mesh (0 when it holds no binding)."""
    slots = 0
    while mesh.attributes.get(index_name(slots)) is not None:
        slots += 1
    return slots


def read_rest(mesh):
    """The rest positions the weights reproduce, stored beside the slots: (m, 3) float64."""
    values = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.attributes[REST_NAME].data.foreach_get("vector", values)
    return values.reshape(-1, 3).astype(np.float64)


def read(mesh):
    """The slots stored on a mesh: index (m, K) int32 and weight (m, K) float32."""
    slots = slot_count(mesh)
    count = len(mesh.vertices)
    index = np.zeros((count, slots), dtype=np.int32)
    weight = np.zeros((count, slots), dtype=np.float32)
    column = np.empty(count, dtype=np.int32)
    values = np.empty(count, dtype=np.float32)
    for slot in range(slots):
        mesh.attributes[index_name(slot)].data.foreach_get("value", column)
        index[:, slot] = column
        mesh.attributes[weight_name(slot)].data.foreach_get("value", values)
        weight[:, slot] = values
    return index, weight


def remove(mesh):
    """Delete every attribute this add-on wrote, leaving the mesh's own attributes as they were."""
    for name in binding_names(mesh):
        mesh.attributes.remove(mesh.attributes[name])


def memory_bytes(vertex_count, slots):
    """Bytes the cache takes in memory and in the .blend (before compression)."""
    return vertex_count * (slots * (4 + 4) + 3 * 4)
