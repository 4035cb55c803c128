"""The TwinCAT CNC / ISG front end (spec 5): the block parser and sectioned files
(``parser``), typed nodes (``nodes``), the checker, the block compiler (``frontend``) and the
room of stored signals (``signals``), registered with the engine as the dialect's own actions;
``dialect`` is what the runtime asks of it (:mod:`ncgate.interpreter.dialects` finds it).

The engine knows no dialect: it runs what ``frontend.IsgFrontEnd`` compiles, through
``ncgate.interpreter.engine.ports``.  Must not import ``plc`` or ``gateway``.
"""
