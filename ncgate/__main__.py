"""``python -m ncgate``: the same as the ``ncgate`` command."""

from ncgate.gateway.cli.main import entry_point

entry_point()
