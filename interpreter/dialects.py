"""The registry of dialects: the one module outside the dialects' folders that may name them.

A dialect registers itself with one line, its member of
:class:`~ncgate.interpreter.settings.Dialect` (``ISG = "isg"``): the config accepts the name
(``nc.dialect``), and :func:`dialect_of` finds ``DIALECT`` in the folder of that name
(``ncgate.interpreter.isg.dialect``).  The rest of the runtime asks the
:class:`~ncgate.interpreter.dialect.DialectPlugin` it gets, and never which dialect it is.

The image's notation (``SA10=1``, ``SYVAR1>5``) is also here: the config and the scripts write
image variables as NC-110 does, whatever the programs' dialect.
"""

from __future__ import annotations

import functools
import importlib
from typing import cast

from ncgate.interpreter.dialect import DialectPlugin
from ncgate.interpreter.nc110.notation import ImageVar as ImageVar
from ncgate.interpreter.nc110.notation import comparison as comparison
from ncgate.interpreter.nc110.notation import parse_assignment as parse_assignment
from ncgate.interpreter.nc110.notation import parse_condition as parse_condition
from ncgate.interpreter.settings import Dialect


@functools.cache
def dialect_of(which: Dialect | str) -> DialectPlugin:
    """The dialect by its member of ``Dialect`` or by its name (``"isg"``)."""
    member = Dialect(which)
    module = importlib.import_module(f"ncgate.interpreter.{member.value}.dialect")
    plugin = cast(DialectPlugin, module.DIALECT)
    if plugin.name is not member:
        raise LookupError(f"ncgate.interpreter.{member.value}.dialect is the dialect "
                          f"{plugin.name.value!r}, not {member.value!r}")
    return plugin
