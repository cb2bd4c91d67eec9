"""What the tests share and are not tests themselves: imported as ``helpers.<module>`` (pytest puts tests/ on the path;
a bench script that borrows one puts it there itself).

- ``blender_scenes``: headless Blender scenes for the add-on tests (and the Blender benchmarks);
- ``cage_corpus``: the cage corpus of tests/data/cage-corpus and its variants;
- ``random_cages``: random and made cages for property tests, and a point-in-polygon test;
- ``stages``: the stages of a bind as its progress messages tell them, and instruments on its cancel polls;
- ``extension_session.py``: not imported: a script test_addon_install.py runs in a Blender-like Python.

Fixtures stay in tests/conftest.py, which pytest loads by that name.
"""
