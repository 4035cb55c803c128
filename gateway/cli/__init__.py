"""The ``ncgate`` command line (spec 4.1): ``main`` parses and dispatches; ``check`` and
``serve`` (``ncgate run``) are commands of their own."""
