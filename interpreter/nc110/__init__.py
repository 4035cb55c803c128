"""The NC-110 / NC-200 front end (spec 1): the grammar (``grammar/nc110.lark``), the parser
into typed nodes (``nodes``), the checker, the formatter, the expression compiler
(``evaluate``) and the block compiler that turns a block into engine steps (``compiler``).

``dialect`` is what the runtime asks of it (:class:`~ncgate.interpreter.dialect.DialectPlugin`,
found by :mod:`ncgate.interpreter.dialects`), and ``notation`` the image's notation the config
and scripts share.  A second dialect is a sibling folder with the same parts; the engine knows
neither (it runs what a front end's block compiler gives it, through
``ncgate.interpreter.engine.ports``).
"""
