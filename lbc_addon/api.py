"""Python API for scripts, e.g. ``blender -b scene.blend --python-expr "..."``; runs synchronously.

Example::

    import bpy
    from lbc_addon import api   # inside Blender with the extension enabled: from bl_ext.user_default.lbc import api
    summary = api.bind(bpy.data.objects["Body"], bpy.data.objects["Cage"], resolution=20000)
    print(summary)
    bpy.ops.wm.save_mainfile()
"""

import bpy

from . import deformer, jobs
from .properties import DEFAULT_INFLUENCES, is_bound


def bind(mesh_obj, cage_obj, *, resolution=0, weighting="quadratic", epsilon=0.0, tolerance=0.0, threshold=0.0,
         influences=DEFAULT_INFLUENCES, mode="AUTO", progress=None, cancel=None):
    """Bind ``mesh_obj`` to ``cage_obj`` (replacing an existing binding) and add the deformer.

    Parameters are those of the Bind operator; ``progress(fraction, message)`` and ``cancel() -> bool`` are passed
    to lbc_core. Nothing in the scene changes unless the bind succeeds.

    Returns
    -------
    dict
        ``dimension``, ``control_points``, ``slots`` (K), ``mean_influences``, ``outside``, ``warnings``, ``seconds``.

    Raises
    ------
    lbc_core.CageError
        With lbc_core's message, for a cage or mesh that cannot be bound.
    lbc_core.Cancelled
        When ``cancel()`` turned true.
    """
    request = jobs.snapshot(mesh_obj, cage_obj, bpy.context.evaluated_depsgraph_get(), resolution=resolution,
                            weighting=weighting, epsilon=epsilon, tolerance=tolerance, threshold=threshold,
                            influences=influences, mode=mode)
    result = jobs.solve(request, progress, cancel)
    bound = jobs.apply(request, result)
    settings = bound.lbc
    return {
        "dimension": settings.dimension,
        "control_points": settings.control_points,
        "slots": settings.slots,
        "mean_influences": settings.mean_influences,
        "outside": settings.outside,
        "warnings": list(result.warnings),
        "seconds": settings.bind_seconds,
    }


def unbind(mesh_obj):
    """Remove the binding; the mesh is exactly as before it was bound. Does nothing for an unbound mesh."""
    if is_bound(mesh_obj):
        jobs.remove(mesh_obj)


def status(mesh_obj):
    """(ok, message): whether the deformer of a bound mesh works, and if not, why."""
    return deformer.status(mesh_obj, bpy.context.evaluated_depsgraph_get())
