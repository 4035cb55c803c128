"""The one engine every dialect runs on: processes, decoder and motion queue, sync rules,
deadlock search, the virtual clock.  See ``engine.py`` for the rooms.

Must not import ``ncgate.plc``, ``ncgate.gateway``, ``ncgate.config`` or a front end
(``ncgate.interpreter.nc110``): those come in through :mod:`.ports`.
"""

from ncgate.interpreter.engine.clock import run_through, run_virtual
from ncgate.interpreter.engine.engine import Engine
from ncgate.interpreter.engine.process import Process
from ncgate.interpreter.engine.states import ProcessState, ProcessStatus, WaitKind, WaitRecord
from ncgate.interpreter.engine.trace import Trace

__all__ = ["Engine", "Process", "ProcessState", "ProcessStatus", "Trace", "WaitKind",
           "WaitRecord", "run_through", "run_virtual"]
