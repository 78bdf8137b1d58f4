"""Sound benchmark: the MP4's sound offset read back, and what of the device path this machine
can measure.

1. MP4 offset: a click track (irregular clicks) is muxed by VideoSink at several offsets, frame
   rates and sample rates; the MP4 is decoded by ffmpeg (AAC priming hidden by the edit list, as a
   player sees it) and cross-correlated with the window the sound should have under the video
   (``puppet.sound.window``). offset_samples: how far the decoded track lags (target 0 +/- 1 audio
   frame); length_error_samples: decoded length minus the video's length in samples.
2. Device: with a sound device (PortAudio), the sound's sample 0 against the take's time 0 as the
   stream reports it (outputBufferDacTime of the first block holding sound minus the scheduled
   time 0, less the sample offset inside that block), cold (open then play) against pre-rolled
   (stream open and running, then scheduled). Without one (CI, this machine: no /dev/snd, no
   PortAudio) that skew cannot be measured here, and the table says so. What is measured instead,
   on the same code: the start cost, cold (decode the file, open the player) against pre-rolled
   (schedule time 0 on a running scheduler), CPU time, ratio in one run; and the callback's CPU
   time per 256-sample block against the block's duration (how much of the audio thread's
   deadline it uses).
3. Page: in headless Chromium (Debian's chromium through playwright), the sound's sample 0 as
   played against the take's time 0 on the page's frame clock (performance.now, the clock
   requestAnimationFrame stamps frames with). Time 0 is ``delay`` (the count-in left) after the
   start is asked; the sound is scheduled by studio.js's own audioContext/heardAt/playSound (their
   source, taken from the file), as its recording handler does. Where sample 0 is heard: the
   AudioContext's output timestamp (contextTime <-> performanceTime) taken once the output has
   passed the scheduled time. Cold: no AudioContext until the start is asked (its clock not
   running yet); pre-rolled: made and running before. skew = heard - time 0, ms (positive:
   late). Also the rule studio.js used before (``ctx.currentTime + delay``, output latency
   not counted), pre-rolled, for comparison.
4. perform: a take of ``--perform-seconds`` (60 by default) performed on hw_sim (timing model,
   1 Mbps) as ``puppet perform --sound`` runs it: the sound's take time 0 scheduled when the
   playback phase begins, on the clock the motors' schedule runs on (a device's stream clock is
   that clock on Linux: ALSA's PortAudio time is CLOCK_MONOTONIC). Three servos' Goal Position is
   sampled from the simulated bus in turn, one query every 10 ms, stamped at its middle; their
   lag behind the take at the sound's position (least squares over shifts of 0.5 ms), over the
   whole run and its first and last 10 s (a drift would grow from one to the other); target
   <= 1 frame (33.3 ms at 30 fps).

    python bench/sound.py --json sound.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import soundfile as sf

from puppet.render.sinks import VideoSink
from puppet.sound import load_sound, take_window
from puppet.sound.device import BlockScheduler, DevicePlayer

_spec = importlib.util.spec_from_file_location(
    "sound_clicks", Path(__file__).resolve().parents[1] / "tests" / "sound" / "clicks.py")
clicks = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(clicks)

AAC_FRAME = 1024  # samples in one AAC frame


def decoded(path: Path, rate: int) -> np.ndarray:
    done = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path), "-map",
                           "0:a", "-f", "f32le", "-ac", "1", "-ar", str(rate), "-"],
                          capture_output=True, check=True)
    return np.frombuffer(done.stdout, np.float32)


def mp4_offsets(folder: Path) -> list[dict]:
    cases = []
    for rate in (44100, 48000):
        path = folder / f"clicks{rate}.wav"
        sf.write(path, clicks.click_track(rate, seconds=3.0, channels=2), rate)
        sound = load_sound(path)
        for fps, offset in ((24000 / 1001, 0.0), (25.0, 0.515), (30000 / 1001, -0.2), (30.0, 1.0)):
            frames = round(1.5 * fps)
            out = folder / f"v{rate}_{fps:.3f}_{offset}.mp4"
            with VideoSink(out, fps, sound=sound, sound_offset_s=offset) as video:
                for _ in range(frames):
                    video.write(np.zeros((32, 32, 3), np.uint8))
            audio = decoded(out, rate)
            expected = take_window(sound.samples, rate, offset, 0.0, frames / fps)[:, 0]
            n = min(len(audio), len(expected))
            lag = clicks.lag_samples(audio[:n], expected[:n])
            cases.append({"rate": rate, "fps": round(fps, 3), "offset_s": offset,
                          "offset_samples": lag, "offset_aac_frames": lag / AAC_FRAME,
                          "length_error_samples": len(audio) - len(expected)})
    return cases


def device_skew(sound, repeats: int) -> dict:
    """The skew on a real device, cold and pre-rolled; {"measured": False, ...} without one."""
    probe = DevicePlayer(sound, 0.0)
    if not probe.prepare():
        return {"measured": False, "why": probe.message}
    probe.stop()
    results = {}
    for mode in ("cold", "preroll"):
        skews = []
        for _ in range(repeats):
            player = DevicePlayer(sound, 0.0)
            if mode == "preroll":
                player.prepare()
                time.sleep(0.2)  # the stream runs, playing silence
                zero = player.start()
            else:  # the motion starts now; the stream is opened only now
                motion = time.monotonic()
                player.prepare()
                zero = player.clock() - (time.monotonic() - motion)  # time 0 = when asked
                player.start(zero)
            deadline = time.monotonic() + 2.0
            while player.first_dac is None and time.monotonic() < deadline:
                time.sleep(0.005)
            if player.first_dac is not None:
                skews.append(1e3 * abs(player.first_dac - zero))
            player.stop()
        skews = np.array(skews)
        results[mode] = {"median_ms": float(np.median(skews)), "p95_ms": float(np.percentile(skews, 95)),
                         "worst_ms": float(skews.max()), "n": int(len(skews))}
    return {"measured": True, **results}


def start_costs(path: Path, repeats: int) -> dict:
    """CPU seconds: cold (decode + player made) vs pre-rolled (time 0 scheduled)."""
    cold, warm = [], []
    for _ in range(repeats):
        t = time.process_time()
        sound = load_sound(path)
        scheduler = BlockScheduler(sound.samples, sound.rate, 0.0)
        cold.append(time.process_time() - t)
        t = time.perf_counter()
        scheduler.take_zero = 0.0
        warm.append(time.perf_counter() - t)
    out = np.empty((256, sound.channels), np.float32)
    blocks = 20_000
    t = time.process_time()
    for i in range(blocks):
        scheduler.fill(out, i * 256 / sound.rate)
    per_block = (time.process_time() - t) / blocks
    return {"cold_start_ms": 1e3 * float(np.median(cold)),
            "preroll_start_us": 1e6 * float(np.median(warm)),
            "cold_over_preroll": float(np.median(cold) / max(np.median(warm), 1e-9)),
            "callback_us_per_256": 1e6 * per_block,
            "callback_share_of_block": per_block / (256 / sound.rate)}


PAGE_DELAY_S = 0.25  # the count-in left when the start is asked (studio: starts_in_s)
STUDIO_JS = Path(__file__).resolve().parents[1] / "puppet" / "view" / "static" / "studio.js"
PAGE_SKEW = """async ([mode, rule, delay, n]) => {
  const sleep = ms => new Promise(r => setTimeout(r, ms));
  const rate = 48000;
  audio.buffer = new AudioBuffer({ length: rate, sampleRate: rate });
  audio.ctx = null;
  if (mode === "preroll") { await audioContext().resume(); await sleep(300); }
  const skews = [];
  for (let i = 0; i < n; i++) {
    const zero = performance.now() + delay * 1000;       // the take's time 0 (audio.recordZero)
    if (rule === "studio") playSound(0, delay, 1, null);  // as studio.js's recording handler
    else { const ctx = audioContext(), source = ctx.createBufferSource();
      source.buffer = audio.buffer; source.connect(ctx.destination);
      source.start(ctx.currentTime + delay);
      audio.source = source; audio.starts.push({ when: ctx.currentTime + delay }); }
    const ctx = audio.ctx, when = audio.starts.at(-1).when;
    let ts = ctx.getOutputTimestamp();
    const deadline = performance.now() + 5000;
    while (!(ts.contextTime >= when) && performance.now() < deadline) {
      await sleep(5); ts = ctx.getOutputTimestamp(); }
    skews.push(ts.performanceTime + (when - ts.contextTime) * 1000 - zero);
    stopSound();
    if (mode === "cold") { await ctx.close(); audio.ctx = null; } else await sleep(50);
  }
  if (audio.ctx) await audio.ctx.close();
  return skews;
}"""


def studio_functions(*names: str) -> str:
    """The source of studio.js's functions ``names`` (each from ``function NAME(`` to its
    closing brace), to run in a page of their own."""
    text = STUDIO_JS.read_text()
    out = []
    for name in names:
        start = text.index(f"function {name}(")
        depth, i = 0, text.index("{", start)
        while True:
            depth += {"{": 1, "}": -1}.get(text[i], 0)
            if depth == 0:
                break
            i += 1
        out.append(text[start:i + 1])
    return "\n".join(out)


def page_skew(repeats: int) -> dict:
    """The page's skew (ms) per case: "cold studio", "preroll studio" (studio.js's scheduling)
    and "preroll currentTime" (the rule it replaced)."""
    import shutil

    from playwright.sync_api import sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        return {"measured": False, "why": "no chromium (apt-get install chromium)"}
    out = {"measured": True, "delay_s": PAGE_DELAY_S}
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=chromium, headless=True,
            args=["--disable-gpu", "--no-sandbox", "--disable-dev-shm-usage",
                  "--autoplay-policy=no-user-gesture-required"])
        try:
            page = browser.new_page()
            page.set_content("<!doctype html><title>sound skew</title><script>"
                             "const audio = {ctx: null, buffer: null, source: null, starts: []};\n"
                             + studio_functions("audioContext", "stopSound", "heardAt", "playSound")
                             + "</script>")
            out["output_latency_ms"] = 1e3 * page.evaluate(
                "(async () => { const c = new AudioContext({latencyHint: 'interactive'}); "
                "await c.resume(); await new Promise(r => setTimeout(r, 200)); "
                "const l = c.outputLatency + c.baseLatency; await c.close(); return l; })()")
            for mode, rule in (("cold", "studio"), ("preroll", "studio"),
                               ("preroll", "currentTime")):
                skews = np.array(page.evaluate(PAGE_SKEW, [mode, rule, PAGE_DELAY_S, repeats]))
                out[f"{mode} {rule}"] = {
                    "p50_ms": float(np.median(skews)), "p95_ms": float(np.percentile(skews, 95)),
                    "abs_p95_ms": float(np.percentile(np.abs(skews), 95)),
                    "worst_ms": float(skews[np.argmax(np.abs(skews))]), "n": int(len(skews))}
        finally:
            browser.close()
    return out


def _lag_ms(t: np.ndarray, goals: np.ndarray, take_t: np.ndarray, take: np.ndarray) -> float:
    """How far goals sampled at times t (n,) lag the take (its readings at take_t, values take),
    ms: the shift d (+/- MAX_LAG_S, 0.5 ms steps) that brings take(t - d) nearest the goals,
    least squares."""
    shifts = np.arange(-MAX_LAG_S, MAX_LAG_S + 1e-9, 0.0005)
    cost = [np.mean((goals - np.interp(t - d, take_t, take)) ** 2) for d in shifts]
    return float(shifts[int(np.argmin(cost))] * 1e3)


MAX_LAG_S = 0.2


def perform_sync(seconds: float) -> dict:
    """{whole, first, last}: the largest |lag| (ms) of three servos' goals behind the take at
    the sound's position (see 4. in the module text), the samples taken and one frame in ms."""
    import threading

    import hw_sim
    from puppet.drive.perform import PerformOptions, perform
    from puppet.reading import Reading
    from puppet.rig import builtin
    from puppet.take import TakeReader, TakeWriter

    rig = builtin()
    sm = rig.servo_map
    k = len(sm.ids)
    take_t = np.arange(int(seconds * 100) + 1) / 100  # every joint swinging, 0.4 Hz, 100 readings/s
    take = sm.zero + 200 * np.sin(2 * np.pi * 0.4 * take_t[:, None] + np.arange(k))
    chosen = [0, 1, 2]
    zero, samples, done = [], [], threading.Event()
    with tempfile.TemporaryDirectory(prefix="puppet-bench-perform-") as tmp:
        path = Path(tmp) / "swing.mcap"
        with TakeWriter(path, ids=[int(i) for i in sm.ids], models=dict(sm.models),
                        rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
            for t, ticks in zip(take_t, take):
                writer.write(Reading(round(t * 1e9), sm.ids, ticks.astype(np.int32),
                                     np.ones(k, bool)))
        with hw_sim.serve(dict(sm.models), timing=True) as bus:
            def sample() -> None:  # one query each 10 ms, the servos in turn (a light touch
                n = 0              # on the process the motors' loop runs in), stamped mid-query
                while not done.is_set():
                    c = chosen[n % len(chosen)]
                    before = time.monotonic()
                    value = bus.servo(int(sm.ids[c])).get("Goal Position")
                    samples.append((c, (before + time.monotonic()) / 2, value))
                    n += 1
                    done.wait(0.01)

            def on_phase(phase: str) -> None:
                if phase == "playback":  # perform --sound: player.start(player.clock()) here
                    zero.append(time.monotonic())

            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            try:
                with TakeReader(path) as reader:
                    perform(rig, reader, bus.port, PerformOptions(yes=True, watchdog_ms=500.0),
                            log=lambda line: None, on_phase=on_phase)
            finally:
                done.set()
                sampler.join()
    got = np.array(samples)
    out = {"samples": len(samples), "seconds": seconds, "frame_ms": 1e3 / 30.0,
           "load_1min": os.getloadavg()[0]}
    windows = {"whole": (0.5, seconds - 0.5), "first": (0.5, 10.5),
               "last": (seconds - 10.5, seconds - 0.5)}
    for name, (lo, hi) in windows.items():
        lags = []
        for c in chosen:
            mine = got[got[:, 0] == c]
            t = mine[:, 1] - zero[0]
            keep = (t >= lo) & (t <= hi)
            lags.append(_lag_ms(t[keep], mine[keep, 2], take_t, take[:, c]))
        out[name] = max(lags, key=abs)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the figures here")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--perform-seconds", type=float, default=60.0,
                        help="length of the performed take (0: skip)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="puppet-bench-sound-") as tmp:
        folder = Path(tmp)
        cases = mp4_offsets(folder)
        long_path = folder / "song.wav"
        sf.write(long_path, np.tile(clicks.click_track(48000, seconds=2.5, channels=2), (24, 1)), 48000)
        costs = start_costs(long_path, args.repeats)
        device = device_skew(load_sound(long_path), args.repeats)
    page = page_skew(args.repeats)
    performed = perform_sync(args.perform_seconds) if args.perform_seconds > 0 else None
    print(f"{'rate':>6} {'fps':>7} {'offset s':>9} {'lag samples':>12} {'AAC frames':>11} {'len err':>8}")
    for c in cases:
        print(f"{c['rate']:>6} {c['fps']:>7.3f} {c['offset_s']:>9.3f} {c['offset_samples']:>12d} "
              f"{c['offset_aac_frames']:>11.4f} {c['length_error_samples']:>8d}")
    print(f"\nstart, a 60 s stereo 48 kHz WAV (CPU): cold (decode + player) "
          f"{costs['cold_start_ms']:.2f} ms, pre-rolled (schedule time 0) "
          f"{costs['preroll_start_us']:.2f} us: {costs['cold_over_preroll']:.0f}x")
    print(f"callback: {costs['callback_us_per_256']:.2f} us CPU per 256-sample block "
          f"({100 * costs['callback_share_of_block']:.3f} % of the block's {256 / 48:.2f} ms)")
    if device["measured"]:
        for mode in ("cold", "preroll"):
            d = device[mode]
            print(f"device skew {mode}: median {d['median_ms']:.2f} ms, p95 {d['p95_ms']:.2f} ms, "
                  f"worst {d['worst_ms']:.2f} ms (n={d['n']})")
    else:
        print(f"device skew: not measured on this machine: {device['why']}")
    if page["measured"]:
        print(f"\npage skew (headless Chromium, sample 0 heard - take time 0, frame clock; "
              f"time 0 {1e3 * page['delay_s']:.0f} ms after the start; output latency "
              f"{page['output_latency_ms']:.1f} ms; target |skew| p95 <= 5 ms pre-rolled)")
        print(f"{'case':<22} {'p50 ms':>8} {'p95 ms':>8} {'|p95| ms':>9} {'worst ms':>9} {'n':>4}")
        for case in ("cold studio", "preroll studio", "preroll currentTime"):
            d = page[case]
            print(f"{case:<22} {d['p50_ms']:>8.2f} {d['p95_ms']:>8.2f} {d['abs_p95_ms']:>9.2f} "
                  f"{d['worst_ms']:>9.2f} {d['n']:>4d}")
    else:
        print(f"page skew: not measured: {page['why']}")
    if performed is not None:
        print(f"\nperform (hw_sim, 1 Mbps, {performed['seconds']:g} s, {performed['samples']} goal "
              f"samples): the goals' lag behind the take at the sound's position: whole "
              f"{performed['whole']:.1f} ms, first 10 s {performed['first']:.1f} ms, last 10 s "
              f"{performed['last']:.1f} ms (target <= 1 frame, {performed['frame_ms']:.1f} ms; load "
              f"{performed['load_1min']:.1f}: a loaded host's late cycles read as lag)")
    if args.json:
        Path(args.json).write_text(json.dumps({"mp4": cases, "start": costs, "device": device,
                                               "page": page, "perform": performed}, indent=1))


if __name__ == "__main__":
    sys.exit(main())
