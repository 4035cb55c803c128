"""What users' own test suites use: the pytest plugin (``ncgate[pytest]``), the virtual-PLC
Modbus client (``modbus_kit``), the CANopen master (``canopen_kit``), and :func:`replay`,
which turns a session recorded at the machine (``ncgate run --record``) into a regression
test."""

from __future__ import annotations

from pathlib import Path

from ncgate.gateway.record import ReplayResult
from ncgate.gateway.record import replay as _replay


def replay(record: str | Path, config: str | Path | None = None,
           tolerance_ms: float = 10.0) -> ReplayResult:
    """Replay a recorded session on the virtual clock; AssertionError with the first
    divergence (recorded vs replayed) unless every process did the same, in the same order,
    within ``tolerance_ms`` of machine time.  In a test, relative paths are relative to the
    test file's folder.

        def test_the_field_problem_of_march_3():
            replay("sessions/2026-03-03.jsonl")
    """
    from ncgate.gateway.testing.pytest_plugin import from_test_folder

    result = _replay(from_test_folder(record) or record, from_test_folder(config),
                     tolerance_ms)
    if result.divergence is not None:
        raise AssertionError(result.divergence)
    return result


__all__ = ["replay"]
