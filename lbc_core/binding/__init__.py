"""A bind from start to end: the one options record (:mod:`.options`), the stages run in order with one progress bar
and clock (:mod:`.pipeline`, :func:`~lbc_core.binding.pipeline.bind`), the :class:`~lbc_core.binding.record.Binding`
they make (deform, save, load: :mod:`.record`), and the warm re-bind after a cage edit, which runs the same stage
functions on the previous binding's mesh (:mod:`.rebinding`). This is the layer the faces (the package, the command
line, the add-on's API) call.
"""
