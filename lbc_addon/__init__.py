"""LBC cage deformation for Blender: bind meshes to a cage with Local Barycentric Coordinates, deform live.

The weights come from ``lbc_core`` (bundled as a wheel in the extension); this package holds only the Blender side:
properties, operators, the Geometry Nodes deformer, panels and a script API. ``register()`` also works from a plain
Python with the ``bpy`` module (tests, background scripts).

Three parts: what reads Blender (``geometry``: the scene into a bind request), what runs without ``bpy`` (``jobs``:
the request, the solve on a worker thread, the result; importable and tested without Blender, so this file imports
the Blender modules only when the add-on is registered), and what writes Blender (``writing``, ``storage``, the
deformer: ``node_group``, ``deformer`` (its modifier), ``diagnosis``, ``handlers``; and ``influence``);
``properties``, ``operators``, ``ui`` and ``api`` are the user's side. Make Cage has its own three: ``cage_scene``
(reads and writes Blender), ``cage_job`` (runs without ``bpy``) and ``cage_maker`` (its operators).
"""


def _modules():
    """The modules with a register(), in registration order."""
    from . import cage_maker, handlers, operators, properties, ui

    return (properties, operators, cage_maker, ui, handlers)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
