"""Flood protection for a server of puppet (the live view's, the Blender link's): rate limits per
connection, notices merged per kind, a bounded JSON parse.

One client must not cost the others anything: every page input passes a ``RateLimit`` before it
is even parsed, ``parse_message`` refuses nesting before ``json`` recurses, and notices (to a
page or to the server's log) go through a ``Throttle`` that lets the first of a kind out at once
and merges the rest of that kind into one line every ``every_s`` seconds.
"""

from __future__ import annotations

import json

#: Opening brackets ('[' and '{') a page message may hold: the page sends flat objects (one).
MAX_BRACKETS = 8


class RateLimit:
    """A token bucket: ``rate_per_s`` messages per second on average, ``burst`` at once."""

    def __init__(self, rate_per_s: float, burst: float):
        self.rate_per_s = float(rate_per_s)
        self.burst = float(burst)
        self._tokens = float(burst)
        self._t = None
        self.refused = 0

    def take(self, now: float) -> bool:
        """True when a message may pass at ``now`` (seconds, monotonic); else counts a refusal."""
        if self._t is not None:
            self._tokens = min(self.burst, self._tokens + (now - self._t) * self.rate_per_s)
        self._t = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self.refused += 1
        return False


class Throttle:
    """Notices merged per kind: ``offer`` lets the first of a kind through at once, holds later
    ones of that kind for ``every_s`` seconds (counting them), and ``due`` hands out one merged
    line per held kind once its time has come. Kinds are a fixed set named in code."""

    def __init__(self, every_s: float = 2.0):
        self.every_s = float(every_s)
        self._last: dict[str, float] = {}
        self._held: dict[str, tuple[str, int]] = {}   # kind -> (newest text, count held)

    def offer(self, kind: str, text: str, now: float) -> str | None:
        """The text to send now, or None when it is held (merged into a later line)."""
        last = self._last.get(kind)
        if last is None or now - last >= self.every_s:
            self._last[kind] = now
            return text
        _, count = self._held.get(kind, ("", 0))
        self._held[kind] = (text, count + 1)
        return None

    def due(self, now: float) -> list[str]:
        """Merged lines of the kinds whose hold ended: the newest text and how many were held."""
        out = []
        for kind, (text, count) in list(self._held.items()):
            if now - self._last[kind] >= self.every_s:
                del self._held[kind]
                self._last[kind] = now
                out.append(text if count == 1 else f"{text} (and {count - 1} more like it)")
        return out


def parse_message(text: str):
    """The JSON object in ``text`` (a dict), or None when it is not one, or nests deeper than
    MAX_BRACKETS brackets (counted before parsing: ``json`` recurses once per level)."""
    if text.count("[") + text.count("{") > MAX_BRACKETS:
        return None
    try:
        message = json.loads(text)
    except (ValueError, RecursionError):
        return None
    return message if isinstance(message, dict) else None
