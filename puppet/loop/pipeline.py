"""Pipeline: per-rig state that turns readings into solved transforms and rendered frames.

    reading -> ServoMap.angles -> forward kinematics (rotations, poses) -> LiveSolve -> T
            -> Renderer.draw(T) -> (h, w, 3) uint8

One per-frame solve path for every rig: ``puppet.fast.LiveSolve``, whose plain case (nothing
free, no dynamics, no handles) is one pattern with the rig precompute's factor. The servo side
of it (which bones a silent servo frees, dynamics steps from reading times) is
``puppet.loop.dropout``. Everything the per-frame path touches is allocated in ``__init__``.
"""

from __future__ import annotations

import pickle
import time
from dataclasses import dataclass

import numpy as np

from puppet.fast import FastModel
from puppet.fast.factor import Factor
from puppet.fast.live_solve import LiveSolve
from puppet.fast.solver import Dynamics
from puppet.loop.dropout import Dropout, Steps
from puppet.reading import Reading, fault_mask
from puppet.render.passes.antialias import ANTIALIAS, LIVE_PIXELS_PER_TRIANGLE, is_software_gl, resolve_antialias
from puppet.rig import Rig

BONE_KIND_STATES = {"full": "sensed", "relative": "relative", "free": "free"}


def model_for(rig: Rig) -> FastModel:
    """The rig's FastModel (LBS matrix, weights, clusters, reduced energy; disk-cached)."""
    options = rig.solver_options
    return FastModel(rig.V, rig.F, rig.W, clusters=options.clusters,
                     extra_weights=options.extra_weights, energy=options.energy)


@dataclass
class RigPrecompute:
    """A rig's solve precompute, made once and shared (batch workers, Ray's object store).

    model:  the FastModel (LBS matrix inputs, weights, clusters, reduced matrices Q, K).
    factor: the global step's factorization for ``rig.pattern()`` (G, P2, H).
    seconds: wall time it took to build (a cache hit in the FastModel makes it short).
    """

    model: FastModel
    factor: Factor
    seconds: float = 0.0

    @classmethod
    def for_rig(cls, rig: Rig) -> RigPrecompute:
        """Build the model and factor the rig's pattern (what every Pipeline on ``rig`` needs)."""
        start = time.perf_counter()
        model = model_for(rig)
        factor = model.solver(rig.pattern()).factor
        return cls(model, factor, time.perf_counter() - start)

    def nbytes(self) -> int:
        """Size of the pickled precompute in bytes: what is sent once to each worker."""
        return len(pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL))


class Pipeline:
    """Per-rig state that turns readings into solved transforms and rendered frames.

    rig:        the character and its servo map (calibration already applied).
    iterations: FAST local/global iterations per frame (warm-started from the last frame).
    render:     build a Renderer (False for solve-only work: exports, records).
    width, height: frame size, pixels.
    antialias:  'msaa' (4 samples), 'fxaa' (a filter over the character's rectangle on screen,
                blurring only the edge pixels), 'none', or 'auto': MSAA on a hardware GL, FXAA on
                a software rasterizer (Mesa llvmpipe), where MSAA triples the mesh pass and FXAA
                costs about 2.5 ms of CPU at 640x480, spread over the rasterizer's threads. A mode
                this GL cannot do raises RenderError naming those it can.
    overlay:    draw the skeleton with bones coloured by state.
    live:       frames for a live loop (demo, live, a view): on a software rasterizer a dense
                character is drawn simplified, one triangle per LIVE_PIXELS_PER_TRIANGLE pixels
                (Renderer's triangle_budget); False: every triangle (playback into files).
    render_options: more Renderer keywords (weight_layout, fxaa_region, ...), for benchmarks.
    precompute: a RigPrecompute of this rig made earlier (shared by many pipelines); None builds
                the model (its disk cache may make that quick) and factors the pattern here.

    Fields: model (FastModel), live (the LiveSolve; solver, pattern, values and handle_targets
    are its current ones), T (4m, 3) float32 handle transforms, angles (k,) float64 radians in
    servo-map order, renderer; solve_ns / iterate_ns / solver_iterations: the solve stage's and
    the native iterations' own nanoseconds, and the iterations, summed over all frames.
    """

    def __init__(self, rig: Rig, *, iterations: int = 8, render: bool = True, width: int = 640,
                 height: int = 480, antialias: str = "auto", overlay: bool = False,
                 render_options: dict | None = None, precompute: RigPrecompute | None = None,
                 live: bool = False):
        if antialias not in ANTIALIAS:
            raise ValueError(f"antialias: {antialias!r} is not one of {ANTIALIAS}")
        self.rig = rig
        self.iterations = int(iterations)
        if precompute is None:
            self.model = model_for(rig)
        else:
            if precompute.model.n != len(rig.V) or precompute.model.m_bones != rig.skeleton.bone_count:
                raise ValueError(f"precompute: made for {precompute.model.n} vertices and "
                                 f"{precompute.model.m_bones} bones, the rig has {len(rig.V)} and "
                                 f"{rig.skeleton.bone_count}")
            self.model = precompute.model
        extras = rig.extras
        d = extras.dynamics
        dynamics = None if d is None else Dynamics(dt=d.dt, density=d.density, damping=d.damping,
                                                   gravity=d.gravity)
        self.live = LiveSolve(self.model, rig.pattern, contact_targets=rig.contact_targets(),
                              dynamics=dynamics, blend_frames=extras.blend_frames,
                              factor=precompute.factor if precompute is not None else None)
        self.dropout = Dropout(rig)
        self.steps = Steps(d)
        self.T = self.model.rest_T()
        self.angles = np.zeros(len(rig.servo_map), np.float64)
        b = rig.skeleton.bone_count
        self._rot = np.empty((b, 3, 3))
        self._pose = np.empty((b, 3, 4))
        self.solve_ns = 0           # the whole solve stage (angles .. iterations), all frames
        self.iterate_ns = 0         # the native iterations alone, all frames
        self.solver_iterations = 0  # iterations run, all frames
        # Bone state per bone, and which bone each servo senses (for the "fault" colour: a servo
        # held at fault; one held only because its reply came late keeps its bone's colour).
        kinds = rig.bone_kinds()
        index = {name: i for i, name in enumerate(rig.skeleton.names)}
        self._base_states = ["free"] * len(rig.skeleton.names)
        for kind, names in kinds.items():
            for name in names:
                self._base_states[index[name]] = BONE_KIND_STATES[kind]
        self._servo_bone = [index[s.joint] for s in rig.servo_map.servos]
        self.fault = np.zeros(len(self._servo_bone), bool)  # per servo, this reading (fault_mask)
        self.bone_states = list(self._base_states)
        sk = rig.skeleton  # rest bones for the overlay
        self.bone_segments = np.ascontiguousarray(np.stack([sk.heads, sk.tails], axis=1))  # (b, 2, 3)
        self.overlay = overlay
        self.renderer = None
        self.antialias = "none"
        if render:
            from puppet.render import RenderError, Renderer, create_context
            from puppet.render.context import gl_renderer_name

            self._context = create_context()
            try:
                antialias = resolve_antialias(antialias, gl_renderer_name(self._context),
                                              int(self._context.max_samples))
            except RenderError:
                self._context.release()
                raise
            self.antialias = antialias
            drawing = {}
            if live and is_software_gl(gl_renderer_name(self._context)):
                drawing["triangle_budget"] = width * height // LIVE_PIXELS_PER_TRIANGLE
            drawing.update(render_options or {})
            self.renderer = Renderer(rig.V, rig.F, self.model.weights, width=width, height=height,
                                     samples=4 if antialias == "msaa" else 0,
                                     fxaa=antialias == "fxaa", context=self._context, **drawing)

    @property
    def solver(self):
        """The current pattern's Solver."""
        return self.live.solver

    @property
    def pattern(self):
        """The current constraint pattern (the rig's, plus point handles, minus dropped bones)."""
        return self.live.pattern

    @property
    def values(self):
        """The current pattern's per-frame Values."""
        return self.live.values

    @property
    def handle_targets(self) -> np.ndarray:
        """(h, 3) float32 targets of the point handles, model units (set before each solve)."""
        return self.live.handle_targets

    def restart(self) -> None:
        """The next frame is solved cold, to convergence (a take's first frame after a seek)."""
        self.live.restart()

    def solve(self, reading: Reading) -> np.ndarray:
        """Solve this reading's pose into ``self.T`` (in place) and return it.

        A servo flagged not ok keeps the tick value the reader held for it (its last good one),
        and its bone is painted ``fault`` unless the reading says it was only late
        (``Reading.late``, a busy host: the bone keeps its colour);
        with the rig option ``on_dropout = "free"`` its bones are solved instead once it has been
        silent long enough (puppet.loop.dropout); dynamics step by the readings' times. A
        reading with ``rotations`` (a shot's frame) is posed from them, not from its angles. The
        first frame is iterated to convergence (puppet.fast.live_solve.COLD_TOL).
        """
        start = time.perf_counter_ns()
        rig = self.rig
        rig.servo_map.angles(reading.ticks, out=self.angles)
        free = self.dropout.update(reading)
        steps = self.steps.update(reading.t_ns)
        if reading.rotations is None:
            rig.skeleton.pose(self.angles, out=self._pose, rotations=self._rot)  # one native call
        else:  # a shot's frame: the joints' rotations interpolated between keys
            np.copyto(self._rot, reading.rotations)
            rig.skeleton.pose_from_rotations(self._rot, out=self._pose)
        stats = self.live.solve(free, self._rot, self._pose, self.T, self.iterations, steps)
        self.solve_ns += time.perf_counter_ns() - start
        self.iterate_ns += stats.iterate_ns
        self.solver_iterations += int(stats.iterations)
        if fault_mask(reading, self.fault).any():
            self._mark_fault()
        elif self.bone_states != self._base_states:
            self.bone_states[:] = self._base_states
        return self.T

    def set_handles(self, points) -> float:
        """Hold these points (the live view's dragged point handles) on top of the rig's own
        constraints: a new pattern (refactored on first use, blended in). Returns the seconds
        it took.

        points: ``Pattern.positional`` entries, each a surface point ((v0, v1, v2), (b0, b1, b2))
        (a triangle's corners and barycentric weights) or a vertex index; no repeats, none of the
        rig's pins. Their targets are the rows of ``self.handle_targets`` ((h, 3) float32, model
        units), which start where the points are in the current T (nothing jumps) and are kept
        across solves until the next call; set them before each solve. A PatternError (e.g. a
        point held only by sensed bones: redundant; a malformed point) leaves the current
        pattern in place.
        """
        start = time.perf_counter()
        self.live.set_handles(points, self.T)
        return time.perf_counter() - start

    def _mark_fault(self) -> None:
        """The bones of the servos at fault this reading ``fault``, the others their own state
        (allocates nothing)."""
        self.bone_states[:] = self._base_states
        fault = self.fault
        for k, bone in enumerate(self._servo_bone):
            if fault[k]:
                self.bone_states[bone] = "fault"

    def draw(self) -> np.ndarray:
        """Render the current T: (height, width, 3) uint8 (``render`` then ``read``)."""
        self.render()
        return self.read()

    def render(self) -> None:
        """Issue the frame of the current T (skinning and every pass; see Renderer.render)."""
        if self.renderer is None:
            raise RuntimeError("Pipeline: built with render=False")
        if self.overlay:
            self.renderer.render(self.T, bones=self.bone_segments, bone_states=self.bone_states)
        else:
            self.renderer.render(self.T)

    def read(self) -> np.ndarray:
        """Wait for the issued frame and read it back: (height, width, 3) uint8."""
        return self.renderer.read()

    def deformed(self) -> np.ndarray:
        """(n, 3) float64 deformed vertices V' = M T of the current T (CPU, for exports)."""
        return self.model.deform(self.T)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.release()
            self._context.release()
            self.renderer = None

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
