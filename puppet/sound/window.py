"""The sound as it sounds under a take: the one rule from take time to sound samples.

The sound's sample ``round(offset_s · rate) + round(t · rate)`` plays at take time t (offset_s:
the sound's time at the take's time 0, ``puppet.take.sync.SoundRef``). Before the sound's start
and after its end there is silence. Exports, the video's mux and the device player all take
their samples from here, so they cannot disagree by a sample.
"""

from __future__ import annotations

import numpy as np


def first_sample(offset_s: float, rate: int) -> int:
    """The sound's sample index at take time 0 (negative: the sound starts after time 0)."""
    return round(offset_s * rate)


def take_window(samples: np.ndarray, rate: int, offset_s: float, start_s: float, seconds: float,
                out: np.ndarray | None = None) -> np.ndarray:
    """(n, channels) float32: the sound from take time start_s for ``seconds``, silence where the
    sound has none; n = round(seconds · rate).

    samples: (frames, channels) float32 sound; rate: Hz; out: (n, channels) float32 to fill
    (reused by a player), or None for a new array.
    """
    n = round(seconds * rate)
    channels = samples.shape[1]
    if out is None:
        out = np.empty((n, channels), np.float32)
    elif out.shape != (n, channels):
        raise ValueError(f"take_window: out is {out.shape}, needs ({n}, {channels})")
    return fill_from(samples, first_sample(offset_s, rate) + round(start_s * rate), out)


def fill_from(samples: np.ndarray, begin: int, out: np.ndarray) -> np.ndarray:
    """out (n, channels) = samples[begin : begin + n], silence where that runs off the sound
    (begin may be negative); allocates nothing."""
    n = out.shape[0]
    lo, hi = max(begin, 0), min(begin + n, samples.shape[0])
    if hi <= lo:
        out.fill(0.0)
        return out
    out[: lo - begin] = 0.0
    out[lo - begin : hi - begin] = samples[lo:hi]
    out[hi - begin :] = 0.0
    return out


def cut_at_take_end(frames: int, rate: int, offset_s: float, take_seconds: float) -> float:
    """Seconds of the sound that play after the take's end (0 when it ends in time)."""
    end = first_sample(offset_s, rate) + round(take_seconds * rate)
    return max(0, frames - end) / rate
