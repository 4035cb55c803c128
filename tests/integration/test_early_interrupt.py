"""A Ctrl-C while ``ncgate`` is still starting -- importing what it needs, or reading its
command line, before ``run`` takes SIGINT over -- ends it quietly: no KeyboardInterrupt
traceback.  The interrupt is put where a Ctrl-C lands in the first tenths of a second (an
import of the command's modules, the start of the command), in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

IN_IMPORT = """
import builtins, sys
real = builtins.__import__
def hit(name, *args, **kwargs):
    if name == "ncgate.gateway.cli.main":
        raise KeyboardInterrupt  # as a Ctrl-C does, inside the import
    return real(name, *args, **kwargs)
builtins.__import__ = hit
"""
IN_MAIN = """
import sys
import ncgate.gateway.cli.main as cli
def hit(argv=None):
    raise KeyboardInterrupt  # as a Ctrl-C does, while the command line is read
cli.main = hit
"""


@pytest.mark.parametrize("where", [IN_IMPORT, IN_MAIN])
@pytest.mark.parametrize(("command", "status", "said"), [
    ("run", 0, "ncgate run: stopped before serving (SIGINT)"),
    ("check", 130, "ncgate check: interrupted"),
])
def test_a_ctrl_c_while_the_command_starts_is_one_line(where: str, command: str, status: int,
                                                       said: str) -> None:
    script = textwrap.dedent(where) + textwrap.dedent(f"""
        sys.argv = ["ncgate", "{command}"]
        from ncgate._start import main
        main()
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, check=False)
    assert "Traceback" not in done.stderr and "KeyboardInterrupt" not in done.stderr, \
        done.stderr
    assert done.stderr.strip() == said
    assert done.returncode == status
