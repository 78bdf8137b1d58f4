"""The page's playback controls (``puppet play TAKE --view``): pause, play, seek, speed."""

from __future__ import annotations

from puppet.errors import PuppetError


class Playback:
    """Controls of the loop's reading source: a TakeSource has them; any other refuses."""

    def __init__(self, source):
        self._source = source

    def state(self) -> dict | None:
        """The source's playback state for the page, or None (no controls)."""
        state = getattr(self._source, "state", None)
        return state() if callable(state) else None

    def control(self, action: str, value: float) -> None:
        source = self._source
        if not hasattr(source, "seek"):
            raise PuppetError("playback controls need 'puppet play TAKE --view'")
        if action == "pause":
            source.pause()
        elif action == "play":
            source.play()
        elif action == "seek":
            source.seek(value)
        else:
            source.set_speed(value)
