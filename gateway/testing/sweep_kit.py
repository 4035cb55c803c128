"""A sweep as a parametrised test: one test per variant (``ncgate_sweep``).

In your tests::

    from ncgate.gateway.testing import ncgate_sweep

    test_library = ncgate_sweep("sweeps/library.toml")

collects one test per variant of the spec (a relative path is relative to the test file's
folder), named by the variant's id and values, in the order of the ids: every pytest-xdist
worker collects the same list, so ``pytest -n auto`` shares the variants out.  A variant
passes when its verdict is in ``allow`` (``ok`` unless given); a failure says the verdict,
the report's line and the ``ncgate sim`` command that reproduces it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from ncgate.gateway.sweep.run import VERDICTS, run_variant
from ncgate.gateway.sweep.spec import Variant, load_spec
from ncgate.gateway.sweep.table import command_of


def ncgate_sweep(spec: str | Path, *, allow: Iterable[str] = ("ok",),
                 timeout_s: float | None = 60.0) -> Callable[[Variant], None]:
    """The test function of ``spec``'s variants, parametrised by ``variant``."""
    import pytest

    allowed = frozenset(allow)
    unknown = allowed - set(VERDICTS)
    if unknown:
        raise ValueError(f"allow: unknown verdicts {sorted(unknown)} (there are: "
                         f"{', '.join(VERDICTS)})")
    path = Path(spec)
    if not path.is_absolute():  # relative to the calling test file, as the other kit paths
        caller = sys._getframe(1).f_globals.get("__file__")
        if caller:
            path = Path(caller).resolve().parent / path
    variants = load_spec(path).variants

    def name(variant: Variant) -> str:
        values = ",".join(f"{k}={v}" for k, v in variant.sets)
        return f"{variant.id}-{Path(variant.program).stem}" + (f"-{values}" if values else "")

    @pytest.mark.parametrize("variant", variants, ids=[name(v) for v in variants])
    def test_variant(variant: Variant) -> None:
        result: dict[str, Any] = run_variant(variant, timeout_s)
        if result["verdict"] not in allowed:
            raise AssertionError(f"{result['verdict']}: {result['report']}\n"
                                 f"reproduce: {command_of(variant, result['signature'])}")

    return test_variant
