"""``python -m gateway``: the same as the ``ncgate`` command."""

from gateway.cli import entry_point

entry_point()
