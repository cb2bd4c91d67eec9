"""What LBC is measured against and by: other coordinates bound through the same stages (mean value, harmonic,
bounded biharmonic: :mod:`.baselines`), the paper's locality statistics P(t), Q(k) and Table 1 (:mod:`.statistics`),
and their figures (:mod:`.plots`). Nothing in a bind depends on this package.
"""
