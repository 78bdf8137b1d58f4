"""The live session: one composition of a reading source, the one Pipeline and a set of outputs,
with one start order, one stop order and one rule for what a stop keeps. Every live command
(demo, live, record, view, play, keys) builds one and runs it; the command line prints its
summary.

Start order (``run``): every output is checked (paths by the output rule, folders writable,
addresses bound: a mistake fails here, before any servo is touched, naming the output); the
source begins (the bus reader's child starts while the pipeline is built: precompute, GL
context, shaders); the source is ready (its setup said); the outputs open (files, then the link,
then the view: it serves last); the loop runs until its end, ``seconds``, an output's
``finished`` or a signal (``puppet.session.signals``).

Stop order, on every way out (the end, a signal, an error): the source stops first (its reader
turns the actuators' torque off and reads it back), then the outputs close in reverse order of
opening, by the one rule (``puppet.session.outputs``: what was made is kept and finished), then
the pipeline. Every output is closed even when one fails; the first error is raised after all.
A signal during the stop only hurries it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from puppet.errors import PuppetError
from puppet.loop.run import LIVE_FPS
from puppet.session.outputs import Link, OutputError, View
from puppet.session.signals import Signals
from puppet.session.sources import FRAMES


def _open_order(output) -> int:
    """Files and hooks first, then the link, then the view (it starts serving)."""
    return 2 if isinstance(output, View) else 1 if isinstance(output, Link) else 0


class Session:
    """One live session.

    rig: the rig (calibration applied). source: one of ``puppet.session.sources``. outputs:
    ``puppet.session.outputs`` instances. inputs: files the command reads (no output may be one
    of them). seconds: the loop's length (None: until the source ends, an output finishes or a
    signal; counted from the take's time 0). solve: build the pipeline (False: readings only, ``puppet record``).
    pipeline: Pipeline keywords (iterations, width, height, antialias, overlay, live,
    render_options). video_fps: the rate sinks are fed at by wall clock (live sources).
    latch_fps: late latching's target (live sources; None: off). on_frame(frames done): after
    each frame (a progress bar). tell(text): where notes are said (stderr); say_setup: the bus
    setup's changes among them (the demo's simulated servos: no). count_in_s: seconds from the
    outputs' opening to the take's time 0 (``take_zero_ns``): the take records, and the sound
    plays, from there.

    After ``run()``: ``summary`` (puppet.loop.Summary), ``setup`` (the bus setup report or None),
    ``stopped_by`` (the first signal's name, or None), ``signals``.
    """

    def __init__(self, rig, source, outputs: Sequence = (), *, inputs: Sequence = (),
                 seconds: float | None = None, solve: bool = True, pipeline: dict | None = None,
                 video_fps: float = 30.0, latch_fps: float | None = LIVE_FPS,
                 on_frame: Callable[[int], None] | None = None,
                 tell: Callable[[str], None] = print, say_setup: bool = True,
                 count_in_s: float = 0.0) -> None:
        self.rig = rig
        self.source = source
        self.outputs = sorted(outputs, key=_open_order)
        self.inputs = [i for i in inputs if i is not None]
        self.seconds = seconds
        self.solve = solve
        self.pipeline_options = dict(pipeline or {})
        self.video_fps = video_fps
        self.latch_fps = latch_fps
        self.on_frame = on_frame
        self.tell = tell
        self.say_setup = say_setup
        self.count_in_s = float(count_in_s)
        self.take_zero_ns = 0    # when the count-in ends and the sound starts (monotonic ns)
        self.record_from_ns = 0  # the first reading a take keeps is the first from here on
        self.pipeline = None
        self.summary = None
        self.setup = None
        self.stopped_by: str | None = None
        self.signals: Signals | None = None

    # ---- start ---------------------------------------------------------------------------------
    def _check(self, checked: list) -> None:
        from puppet.atomic import check_distinct

        check_distinct({o.option.split(" ", 1)[0]: o.path for o in self.outputs
                        if o.path is not None and o.option})
        views = [o for o in self.outputs if isinstance(o, View)]
        links = [o for o in self.outputs if isinstance(o, Link)]
        if views and links:
            from puppet.link.server import DEFAULT_PORT as LINK_PORT
            from puppet.net.address import one_place, parse_address
            from puppet.view.protocol import DEFAULT_PORT as VIEW_PORT

            view_at = parse_address(views[0].address, option="--view", default_port=VIEW_PORT)
            link_at = parse_address(links[0].address, option="--link", default_port=LINK_PORT)
            if one_place(view_at, link_at):  # e.g. localhost and 127.0.0.1, or 0.0.0.0 and any
                where = (f"{view_at[0]}:{view_at[1]}" if view_at[0] == link_at[0] else
                         f"port {view_at[1]} on {view_at[0]} and {link_at[0]}")
                raise OutputError(f"{views[0].option} and {links[0].option} name one address "
                                  f"({where}): give them two")
        for output in self.outputs:
            checked.append(output)
            output.check(self.inputs)

    def _build_pipeline(self):
        from puppet.loop import Pipeline

        render = any(o.renders for o in self.outputs)
        options = {"render": render, **self.pipeline_options}
        pipeline = Pipeline(self.rig, **options)
        if pipeline.renderer is not None and options.get("live"):
            pipeline.draw()  # compiles the shaders (llvmpipe: at first use) while the source starts
        return pipeline

    def run(self):
        """Start, loop, stop (see the module's docstring); returns the Summary."""
        from puppet.loop import Summary

        checked: list = []
        with Signals() as signals:
            self.signals = signals
            try:
                self._check(checked)
                if not signals.stop:
                    self.source.begin([o.hook for o in self.outputs if o.hook is not None])
                    if self.solve:
                        self.pipeline = self._build_pipeline()
                    self.setup = self.source.ready(self.tell if self.say_setup else None)
                self.take_zero_ns = time.monotonic_ns() + int(self.count_in_s * 1e9)
                # a count-in drops the readings before its end; without one every reading counts
                self.record_from_ns = self.take_zero_ns if self.count_in_s > 0 else 0
                for output in self.outputs:
                    if signals.stop:
                        break
                    output.open(self)
                if not signals.stop:
                    self.summary = self._loop()
            except BaseException:
                self.stopped_by = signals.signal_name
                self._stop(checked, raise_errors=False)  # the error that stopped it is the one said
                raise
            self.stopped_by = signals.signal_name
            self._stop(checked, raise_errors=True)
        if self.summary is None:  # stopped before the loop began
            self.summary = Summary()
        return self.summary

    # ---- the loop ------------------------------------------------------------------------------
    def _loop(self):
        from puppet.loop.run import run_frames, run_live

        sinks = [sink for o in self.outputs for sink in o.sinks]
        recorder = next((o.recorder for o in self.outputs if o.recorder is not None), None)
        view = next((o.view for o in self.outputs if o.view is not None), None)
        link = next((o.link for o in self.outputs if o.link is not None), None)
        after = [o.after_solve for o in self.outputs if o.after_solve is not None]
        feeds = [o.feed for o in self.outputs if o.feed is not None]
        finishing = [o for o in self.outputs if type(o).finished is not False]
        signals = self.signals

        def should_stop() -> bool:
            return signals.stop or any(o.finished for o in finishing)

        frames_done = self.on_frame
        if self.source.kind == FRAMES:
            source = self.source
            done = [0]

            def on_frame(pipeline) -> None:
                if link is not None:
                    link.frame(pipeline, _Stamp(source.shown_ns), take_s=source.take_s)
                done[0] += 1
                if frames_done is not None:
                    frames_done(done[0])

            if link is not None:
                self._wait_for_client(link)
            return run_frames(self.pipeline, source.frames(should_stop),
                              sinks=sinks, on_frame=on_frame,
                              should_stop=should_stop)
        seconds = None if self.seconds is None else self.seconds + self.count_in_s
        return run_live(self.pipeline, self.source.reading_source, seconds=seconds,
                        sinks=sinks, video_fps=self.video_fps,
                        recorder=recorder, should_stop=should_stop,
                        on_frame=None if frames_done is None else (lambda s: frames_done(s.frames)),
                        latch_fps=self.latch_fps, view=view, link=link,
                        after_solve=after[0] if len(after) == 1 else
                        (None if not after else _chain(after)),
                        feed=feeds)

    def _wait_for_client(self, link) -> None:
        """A take streamed to Blender starts once the add-on is there (``play --link``)."""
        self.tell("link: waiting for a client (Ctrl-C stops)")
        while link.clients_seen == 0 and not self.signals.stop:
            time.sleep(0.05)

    # ---- stop ----------------------------------------------------------------------------------
    def _stop(self, checked: list, *, raise_errors: bool) -> None:
        error: BaseException | None = None
        try:
            self.source.stop()
        except PuppetError as err:
            error = err
        for output in reversed(checked):
            try:
                output.close()
            except PuppetError as err:
                error = error or err
        if self.pipeline is not None:
            pipeline, self.pipeline = self.pipeline, None
            pipeline.close()
        if error is not None and raise_errors:
            raise error

    def report(self) -> dict:
        """Every output's lines for the summary, in opening order."""
        lines: dict = {}
        for output in self.outputs:
            lines.update(output.report())
        return lines


def _chain(calls):
    def after_solve(pipeline, reading) -> None:
        for call in calls:
            call(pipeline, reading)
    return after_solve


class _Stamp:
    """A reading's time alone (what ``Link.frame`` reads of it): when the frame was handed out."""

    __slots__ = ("t_ns",)

    def __init__(self, t_ns: int) -> None:
        self.t_ns = t_ns
