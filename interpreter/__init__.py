"""The part-program interpreter: grammar, parser, typed nodes, checker, processes, scheduler.

Uses the standard library and lark only; it never imports ``plc`` or ``gateway``.  What it
needs from the outside (an image to read and wait on, a clock) it states as protocols.
"""
