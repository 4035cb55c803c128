"""The console's state colours read on its backgrounds: WCAG 2.1 AA contrast (4.5:1 for
text) for every state colour and muted text, in the light and the dark theme (IDLE grey was
4.47:1 on a white panel), and every select of the page has an accessible name."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

STATIC = Path(__file__).resolve().parents[3] / "gateway" / "web" / "static"
TEXT = ("wait", "run", "alarm", "idle", "muted", "accent", "fg")
BACKGROUNDS = ("panel", "bg", "faint")


def themes() -> list[dict[str, str]]:
    css = (STATIC / "style.css").read_text()
    blocks = re.findall(r"(:root[^{]*)\{([^}]*)\}", css)
    out = []
    for _, body in blocks:
        colours = dict(re.findall(r"--([\w-]+):\s*(#[0-9a-fA-F]{3,6})", body))
        if "idle" in colours:
            out.append(colours)
    return out


def luminance(colour: str) -> float:
    h = colour.lstrip("#")
    if len(h) == 3:
        h = "".join(c * 2 for c in h)
    channels = [int(h[i:i + 2], 16) / 255 for i in (0, 2, 4)]
    r, g, b = [c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4 for c in channels]
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def contrast(a: str, b: str) -> float:
    high, low = sorted((luminance(a), luminance(b)), reverse=True)
    return (high + 0.05) / (low + 0.05)


@pytest.mark.parametrize("theme", range(3))
def test_every_state_colour_reads_on_every_background(theme: int) -> None:
    colours = themes()[theme]
    poor = [(text, back, round(contrast(colours[text], colours[back]), 2))
            for text in TEXT for back in BACKGROUNDS
            if contrast(colours[text], colours[back]) < 4.5]
    assert poor == []


def test_the_check_sees_a_poor_contrast() -> None:
    assert round(contrast("#777", "#fff"), 2) == 4.48
    assert themes() and len(themes()) == 3


def test_every_select_of_the_page_has_a_name() -> None:
    html = (STATIC / "index.html").read_text()
    selects = re.findall(r"<select[^>]*>", html)
    assert selects and all("aria-label=" in s for s in selects), selects
