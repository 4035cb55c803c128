"""The console's event feed renders lazily and in bounded pieces: a busy cell with no page open
costs a list append per event, and no read of the ring renders more than SINCE_MAX."""

from __future__ import annotations

import asyncio

from ncgate.gateway.web.feed import SINCE_MAX, EventFeed
from ncgate.interpreter.engine import events as ev


async def test_nothing_is_rendered_until_asked_and_a_read_is_bounded() -> None:
    feed = EventFeed(asyncio.get_running_loop())
    for seq in range(1, 2001):
        feed.listen(ev.Hazard(seq, seq / 1000, 1, None, f"h{seq}"))
    feed.flush()
    assert feed.seq == 2000
    assert not any(isinstance(item, str) for _, item in feed._ring)  # nothing rendered yet
    texts, missed = feed.since(0)
    assert (len(texts), missed) == (SINCE_MAX, 0) and '"message": "h1"' in texts[0]
    texts, _ = feed.since(SINCE_MAX)  # the next piece, from where the first stopped
    assert f'"message": "h{SINCE_MAX + 1}"' in texts[0]
    rendered = sum(isinstance(item, str) for _, item in feed._ring)
    assert rendered == 2 * SINCE_MAX  # kept rendered for the next reader
