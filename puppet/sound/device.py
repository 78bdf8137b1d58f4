"""Playing a take's sound on the machine's sound device (sounddevice over PortAudio), pre-rolled.

A cold start (open a stream, then play) puts the stream's opening latency between the motion and
the sound (a robot SDK measured 16 ms median, 46 ms worst); pre-rolled (open and start the
stream ahead, playing silence, then schedule the sound on the stream's own clock) it measured
0.9 ms. So: ``prepare()`` opens and starts the output stream, and the callback plays silence;
``start(take_zero)`` says on the stream's clock when the take's time 0 is; from then on every
block the callback fills is the sound under the take (``puppet.sound.window``) at the time
PortAudio says the block reaches the DAC (``outputBufferDacTime``), so the sound's sample 0 lands
on the take's time 0 whatever the block size and the device's latency. ``stop()`` ends it at once.

A machine with no sound device is normal (CI, a server): ``prepare()`` then returns False and
``message`` says "no sound device: playing silent" with the reason, once; nothing raises.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from puppet.sound.window import fill_from, first_sample

NO_DEVICE = "no sound device: playing silent"


def _sounddevice():
    """The sounddevice module, or (None, why) where PortAudio or the package is missing."""
    try:
        import sounddevice
    except (OSError, ImportError) as err:  # PortAudio is not installed, or no package
        return None, str(err)
    return sounddevice, None


class BlockScheduler:
    """Fills output blocks with the sound under the take, on a clock given in seconds.

    samples: (frames, channels) float32; rate: Hz; offset_s: the sound's time at take time 0.
    ``take_zero``: the clock time of the take's time 0 (None: silence until it is set).
    ``fill(out, dac_time)``: out (n, channels) float32 gets the samples that play from clock
    time dac_time on (silence before take time 0 and after the sound's end). Allocates nothing.
    """

    def __init__(self, samples: np.ndarray, rate: int, offset_s: float):
        self.samples = samples
        self.rate = int(rate)
        self.first = first_sample(offset_s, rate)
        self.take_zero: float | None = None
        self.stopped = False

    def fill(self, out: np.ndarray, dac_time: float) -> int | None:
        """Fill out for a block reaching the DAC at dac_time; the sound sample index of out[0]
        (None: silence, not started or stopped)."""
        if self.take_zero is None or self.stopped:
            out.fill(0.0)
            return None
        begin = self.first + round((dac_time - self.take_zero) * self.rate)
        fill_from(self.samples, begin, out)
        return begin


class DevicePlayer:
    """The take's sound on the default output device, pre-rolled (see the module docstring).

    sound: a ``puppet.sound.Sound``; offset_s: its time at the take's time 0; device: a
    PortAudio device (None: the default output); latency: PortAudio's ('low').
    available: False when there is no device (``message`` says why, once: NO_DEVICE ...).
    first_dac: the DAC time of the first block that held sound (None until one did).
    """

    def __init__(self, sound, offset_s: float = 0.0, *, device=None, latency="low"):
        self.sound = sound
        self.scheduler = BlockScheduler(sound.samples, sound.rate, offset_s)
        self.device, self.latency = device, latency
        self.available = False
        self.message: str | None = None
        self.first_dac: float | None = None
        self._stream = None
        self._lock = threading.Lock()

    def prepare(self) -> bool:
        """Open and start the output stream, playing silence (the pre-roll); False, with
        ``message``, when there is no sound device."""
        sd, why = _sounddevice()
        if sd is None:
            self.message = f"{NO_DEVICE} ({why})"
            return False
        try:
            self._stream = sd.OutputStream(samplerate=self.sound.rate,
                                           channels=self.sound.channels, dtype="float32",
                                           device=self.device, latency=self.latency,
                                           callback=self._callback)
            self._stream.start()
        except (sd.PortAudioError, ValueError) as err:  # no device, or none that takes the rate
            self._stream = None
            self.message = f"{NO_DEVICE} ({err})"
            return False
        self.available = True
        return True

    def _callback(self, outdata, frames, time_info, status) -> None:
        began = self.scheduler.fill(outdata, time_info.outputBufferDacTime)
        if began is not None and self.first_dac is None and began + frames > 0:
            self.first_dac = time_info.outputBufferDacTime

    def clock(self) -> float:
        """The stream's clock now (seconds), the clock ``start`` takes; time.monotonic() without
        a device."""
        return self._stream.time if self._stream is not None else time.monotonic()

    def start(self, take_zero: float | None = None) -> float:
        """Schedule the take's time 0 at stream clock time take_zero (default: now plus the
        stream's output latency, the soonest a sample can be heard); returns it."""
        if take_zero is None:
            latency = self._stream.latency if self._stream is not None else 0.0
            take_zero = self.clock() + latency
        self.scheduler.take_zero = float(take_zero)
        return self.scheduler.take_zero

    def stop(self) -> None:
        """Silence now and close the stream. Safe to call twice."""
        self.scheduler.stopped = True
        with self._lock:
            stream, self._stream = self._stream, None
        if stream is not None:
            stream.abort()  # drops what is queued: the sound stops with the motion
            stream.close()

    def __enter__(self) -> "DevicePlayer":
        self.prepare()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
