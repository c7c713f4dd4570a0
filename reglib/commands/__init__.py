"""Sub-commands of the ``reglib`` CLI, one module each (see :mod:`reglib.cli`)."""
