"""The NC-110 / NC-200 front end (spec 1): the grammar (``grammar/nc110.lark``), the parser
into typed nodes (``nodes``), the checker, the formatter, the expression compiler
(``evaluate``) and the block compiler that turns a block into engine steps (``compiler``).

A second dialect is a sibling folder with the same parts; the engine knows neither (it runs
what a front end's block compiler gives it, through ``ncgate.interpreter.engine.ports``).
"""
