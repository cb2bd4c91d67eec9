"""LBC cage deformation for Blender: bind meshes to a cage with Local Barycentric Coordinates, deform live.

The weights come from ``lbc_core`` (bundled as a wheel in the extension); this package holds only the Blender side:
properties, operators, the Geometry Nodes deformer, panels and a script API. ``register()`` also works from a plain
Python with the ``bpy`` module (tests, background scripts).
"""

from . import deformer, operators, properties, ui

_MODULES = (properties, operators, ui, deformer)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
