"""The version of lbc_core, apart from the package face so that modules below it can read it."""

__version__ = "0.2.0"
