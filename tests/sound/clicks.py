"""A synthetic click track: short tone bursts at known, irregular times (tests and bench)."""

from __future__ import annotations

import numpy as np

CLICK_TIMES_S = (0.25, 0.61, 1.07, 1.40, 1.93)
"""When each click starts, seconds of sound time (irregular: a correlation has one peak)."""
BURST_S = 0.010
"""Each click: 10 ms of a 1 kHz tone at amplitude 0.8."""


def click_track(rate: int = 48000, seconds: float = 2.5, channels: int = 1,
                times=CLICK_TIMES_S) -> np.ndarray:
    """(frames, channels) float32: silence with a 1 kHz burst starting at each of ``times``."""
    out = np.zeros((round(seconds * rate), channels), np.float32)
    n = round(BURST_S * rate)
    burst = 0.8 * np.sin(2 * np.pi * 1000.0 * np.arange(n) / rate)
    for t in times:
        start = round(t * rate)
        out[start:start + n] = burst[: len(out) - start, None]
    return out


def lag_samples(decoded: np.ndarray, expected: np.ndarray) -> int:
    """Samples by which ``decoded`` (n,) lags ``expected`` (n,) (cross-correlation peak)."""
    n = len(decoded) + len(expected)
    size = 1 << (n - 1).bit_length()
    spectrum = np.fft.rfft(decoded, size) * np.conj(np.fft.rfft(expected, size))
    corr = np.fft.irfft(spectrum, size)
    lag = int(np.argmax(corr))
    return lag if lag < size // 2 else lag - size


def onsets(x: np.ndarray, rate: int, threshold: float = 0.3) -> list[float]:
    """Times (s) where |x| first exceeds threshold after 50 ms of staying under it."""
    loud = np.flatnonzero(np.abs(x) > threshold)
    found, last = [], -10**9
    for i in loud:
        if i - last > 0.05 * rate:
            found.append(i / rate)
        last = i
    return found
