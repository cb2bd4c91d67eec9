"""The ``lbc`` command line: ``lbc bind``, ``cage``, ``deform``, ``stats``, ``compare`` and ``table1``, on top of the
package's public functions (:mod:`.main` reads the flags, :mod:`.commands` runs them, :mod:`.output` prints).
"""

from .main import main

__all__ = ["main"]
