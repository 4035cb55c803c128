"""``python -m ncgate``: the same as the ``ncgate`` command."""

from ncgate._start import main

main()
