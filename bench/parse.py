"""Parse + check speed on a generated 200,000-line program (issue: the front end).

Prints lines/s of ``check_program`` (a full parse with lark and every check) and of a bare
``re.finditer`` tokenisation of the same text, measured in the same run, and their ratio: the
floor for pure Python.  Each figure is the best of several alternating rounds; the parser's
shape cache is emptied before every round, so the cost of learning each shape is included.

    python3 dev.py bench            # or: .venv/bin/python bench/parse.py [--lines N]

Targets: >= 50,000 lines/s, and within 4x of the bare tokeniser.
"""

from __future__ import annotations

import argparse
import gc
import random
import re
import time

from ncgate.interpreter.nc110 import parser as parser_module
from ncgate.interpreter.nc110.checker import CheckContext, check_program
from ncgate.interpreter.nc110.parser import Program

TOKEN = re.compile(
    r'(?P<number>\d+\.?\d*|\.\d+)|(?P<name>[A-Za-z_][A-Za-z0-9_]*)|(?P<string>"[^"\n]*")'
    r"|(?P<comment>;[^\n]*)|(?P<punct>[-+*/=#<>(),.])|(?P<newline>\n)|(?P<space>[ \t]+)"
)


def generate(lines: int, seed: int = 20261121) -> str:
    """A realistic machining program: CAM-like moves, tool changes, loops, syncs, E maths."""
    rng = random.Random(seed)
    out: list[str] = []
    n = 0

    def num(lo: float, hi: float) -> str:
        return f"{rng.uniform(lo, hi):.3f}".rstrip("0").rstrip(".")

    label = 0
    while len(out) < lines:
        n += 10
        r = rng.random()
        if r < 0.45:
            out.append(f"N{n}G1X{num(-400, 400)}Y{num(-300, 300)}F{rng.randint(100, 3000)}")
        elif r < 0.60:
            out.append(f"N{n} G1 X{num(-400, 400)} Y{num(-300, 300)} Z{num(-50, 5)}")
        elif r < 0.72:
            g = rng.choice(("G2", "G3"))
            out.append(f"N{n}{g}X{num(-400, 400)}Y{num(-300, 300)}I{num(-40, 40)}J{num(-40, 40)}")
        elif r < 0.78:
            out.append(f"N{n}G0X{num(-400, 400)}Y{num(-300, 300)}Z{num(5, 50)}")
        elif r < 0.83:
            out.append(f"N{n}E{rng.randint(1, 99)}=E{rng.randint(1, 99)}*{num(0, 2)}+{num(0, 9)}")
        elif r < 0.85:
            out.append(f"N{n}T{rng.randint(1, 30)}.{rng.randint(1, 30)}M6S{rng.randint(500, 6000)}")
        elif r < 0.87:
            out.append(f"N{n}(WAI,SA{rng.randint(0, 1023)}=1)")
        elif r < 0.89:
            out.append(f"N{n}#(SND,{rng.randint(2, 5)})")
        elif r < 0.91:
            out.append(f"N{n}(WAI,{rng.randint(2, 5)})")
        elif r < 0.93:
            out.append(f"N{n}SYVAR{rng.randint(0, 255)}=E{rng.randint(1, 99)}")
        elif r < 0.95:
            out.append(f'"L{label}"')
            label += 1
        elif r < 0.96 and label:
            target = f"L{rng.randrange(label)}"
            out.append(f"N{n}(BLT,E{rng.randint(1, 99)},{rng.randint(1, 9)},{target})")
        elif r < 0.975:
            out.append(f"N{n}(RPT,{rng.randint(2, 5)})")
            out.append(f"N{n + 5}G91G1X{num(0, 5)}")
            out.append(f"N{n + 6}(ERP)")
        elif r < 0.99:
            out.append(f"; {rng.choice(('roughing', 'finishing pass', 'probe', 'clamp check'))}")
        else:
            out.append(f'N{n}(DIS,"pass",E{rng.randint(1, 99)})')
    return "\n".join(out[:lines]) + "\n"


def tokenise(text: str) -> int:
    tokens = [(m.lastgroup, m.group()) for m in TOKEN.finditer(text)]
    return len(tokens)


def parse_and_check(text: str) -> int:
    parser_module._SHAPES.clear()  # learn every shape again: a cold start each round
    program = Program("BENCH", "bench.nc", text)
    diagnostics = check_program(program, CheckContext(runs_in=frozenset({1})))
    errors = [d for d in diagnostics if d.is_error]
    if errors:
        raise SystemExit(f"generated program has errors:\n{errors[0].render()}")
    return len(program)


def best_of(rounds: int, fn: object, text: str) -> float:
    best = float("inf")
    for _ in range(rounds):
        gc.collect()
        start = time.perf_counter()
        fn(text)  # type: ignore[operator]
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--lines", type=int, default=200_000)
    args.add_argument("--rounds", type=int, default=3)
    opts = args.parse_args()
    text = generate(opts.lines)
    lines = text.count("\n")
    parser_module.lark_parser()  # build the LALR tables outside the timing
    tokens = tokenise(text)
    base_s = parse_s = float("inf")
    for _ in range(opts.rounds):  # alternate, so both see the same machine state
        base_s = min(base_s, best_of(1, tokenise, text))
        parse_s = min(parse_s, best_of(1, parse_and_check, text))
    print(f"program: {lines} lines, {tokens} tokens, {len(parser_module._SHAPES)} shapes")
    print(f"bare re.finditer tokeniser: {lines / base_s:12,.0f} lines/s  ({base_s:.3f} s)")
    print(f"parse + check (ncgate):     {lines / parse_s:12,.0f} lines/s  ({parse_s:.3f} s)")
    print(f"ratio parse+check / tokeniser: {parse_s / base_s:.2f}x   "
          f"(targets: >= 50,000 lines/s, <= 4x)")
    one_huge_block()


def one_huge_block() -> None:
    """Issue 9.2: one block of 160,000 words (640 KB) costs what its words cost in a block
    of 16,000: the time per word of the two, and their ratio (1.0 is linear).  The words
    are assignments (E1=2): an address may stand once in a block (NC035), which the block
    of X1Y2 pairs this measured before now breaks."""
    per_word = {}
    for words in (16_000, 160_000):
        text = "N1G1F600" + "E1=2" * words + "\n"
        seconds = best_of(2, parse_and_check, text)
        per_word[words] = seconds / words
        print(f"one block of {words:7,} words ({len(text) / 1024:5.0f} KB): {seconds:.3f} s")
    print(f"time per word, 160,000 vs 16,000: {per_word[160_000] / per_word[16_000]:.2f}x   "
          "(linear: about 1x)")


if __name__ == "__main__":
    main()
