"""Antialias pass: the frame targets, MSAA resolve or FXAA, and which mode a GL gets.

The scene is drawn into ``target`` (multisampled with MSAA, a texture with FXAA, else
``resolved`` itself), then resolved (MSAA) or filtered (FXAA) into ``resolved``, which is read
back. 'auto' is MSAA on a hardware GL and FXAA on a software rasterizer (Mesa llvmpipe), where
MSAA triples the mesh pass and FXAA costs about 2.5 ms of CPU at 640x480.
"""

from __future__ import annotations

import moderngl
import numpy as np

from puppet.render import shaders
from puppet.render.errors import RenderError, RenderInputError
from puppet.render.passes.base import GLPass

ANTIALIAS = ("auto", "msaa", "fxaa", "none")
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "lavapipe")
#: A live loop on a software rasterizer draws at most one triangle per this many pixels of its
#: frame (25 600 at 640x480; the critter has 49 816): see puppet.render.lod.
LIVE_PIXELS_PER_TRIANGLE = 12
#: Where FXAA filters: the character's rectangle on screen (the rest of the frame, ground and
#: background, has no hard edge), or the whole frame.
FXAA_REGIONS = ("character", "frame")
#: How FXAA runs: "mark_edges" (edge pixels marked in the depth buffer, then the blur only
#: there: on llvmpipe half the cost of one pass) or "one_pass" (every pixel tests and blurs).
FXAA_PASSES = ("mark_edges", "one_pass")
#: Pixels around the character's rectangle that FXAA also filters (its 3x3 neighbourhood).
FXAA_MARGIN_PX = 2.0


def is_software_gl(gl_renderer: str) -> bool:
    """True for a CPU rasterizer (Mesa llvmpipe and its kin)."""
    return any(name in gl_renderer.lower() for name in SOFTWARE_GL)


def resolve_antialias(antialias: str, gl_renderer: str, max_samples: int) -> str:
    """The antialiasing mode to use on a GL: 'auto' becomes MSAA on a hardware GL and FXAA on a
    software rasterizer; 'msaa' on a GL without multisampling (max_samples < 2) raises
    RenderError naming the modes this GL can do."""
    software = is_software_gl(gl_renderer)
    available = ("msaa", "fxaa", "none") if max_samples >= 2 else ("fxaa", "none")
    if antialias == "auto":
        return "fxaa" if software or "msaa" not in available else "msaa"
    if antialias not in available:
        raise RenderError(f"antialias {antialias!r}: this GL ({gl_renderer}) cannot do it "
                          f"(max samples {max_samples}); available: {', '.join(available)}")
    return antialias


class AntialiasPass(GLPass):
    """Frame targets of width x height [px] and their antialiasing: samples (0: none, else
    MSAA, already clamped to the driver's maximum), or fxaa with fxaa_region and fxaa_passes."""

    def __init__(self, ctx, *, width: int, height: int, samples: int, fxaa: bool, fxaa_region: str,
                 fxaa_passes: str):
        super().__init__(ctx)
        if fxaa_region not in FXAA_REGIONS:
            raise RenderInputError(f"fxaa_region: expected one of {FXAA_REGIONS}, got {fxaa_region!r}")
        if fxaa_passes not in FXAA_PASSES:
            raise RenderInputError(f"fxaa_passes: expected one of {FXAA_PASSES}, got {fxaa_passes!r}")
        if fxaa and samples:
            raise RenderInputError(f"fxaa: use it instead of MSAA (samples=0), got samples={samples}")
        self.width, self.height = width, height
        self.samples = samples
        self.fxaa = fxaa
        self.fxaa_region = fxaa_region
        self._vaos = []
        self.rect = None  # the rectangle (x, y, w, h) [px] FXAA filtered last (None: the frame)
        self._corners = np.ones((8, 4), dtype=np.float32)
        self._clip = np.zeros((8, 4), dtype=np.float32)
        with self.building():
            self._build(fxaa_passes)

    def _framebuffer(self, color, depth):
        return self.own(self.ctx.framebuffer(self.own(color), self.own(depth)))

    def _build(self, fxaa_passes: str) -> None:
        ctx = self.ctx
        size = (self.width, self.height)
        self.resolved = self._framebuffer(ctx.renderbuffer(size, 4), ctx.depth_renderbuffer(size))
        if self.samples:
            self.target = self._framebuffer(ctx.renderbuffer(size, 4, samples=self.samples),
                                            ctx.depth_renderbuffer(size, samples=self.samples))
        elif self.fxaa:
            self._aliased = ctx.texture(size, 4)
            self._aliased.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._aliased.repeat_x = self._aliased.repeat_y = False
            self.target = self._framebuffer(self._aliased, ctx.depth_renderbuffer(size))
            fragments = {"one_pass": [shaders.FXAA_FRAGMENT],
                         "mark_edges": [shaders.FXAA_MARK_FRAGMENT, shaders.FXAA_BLUR_FRAGMENT]}[fxaa_passes]
            for fragment in fragments:
                prog = self.own(ctx.program(vertex_shader=shaders.source(shaders.FXAA_VERTEX),
                                            fragment_shader=shaders.source(fragment)))
                if "u_texel" in prog:  # the mark pass does not blur: no texel size
                    prog["u_texel"].value = (1.0 / self.width, 1.0 / self.height)
                prog["u_image"].value = 2
                self._vaos.append(self.own(ctx.vertex_array(prog, [])))
        else:
            self.target = self.resolved

    def finish(self, character_box: np.ndarray | None, view_proj_gl: np.ndarray, margin_px: float) -> None:
        """Resolve (MSAA) or filter (FXAA) the drawn target into ``resolved``. character_box:
        (2, 3) world [min, max] holding the character, margin_px: added around its projection
        (FXAA over the character's rectangle; None: the whole frame)."""
        if self.samples:
            self.ctx.copy_framebuffer(self.resolved, self.target)
        elif self.fxaa:
            rect = None
            if self.fxaa_region == "character" and character_box is not None:
                rect = self.character_rect(character_box, view_proj_gl, margin_px)
            self.rect = rect
            self._fxaa(rect)

    def _fxaa(self, rect) -> None:
        """FXAA from the aliased texture into ``resolved``: only inside rect (x, y, w, h) [px]
        over a copy of the frame (the ground fades out smoothly: no hard edge), or everywhere;
        with fxaa_passes "mark_edges", a first pass marks edge pixels in the depth buffer and
        the blur runs only there (the copy holds every other pixel)."""
        ctx = self.ctx
        resolved = self.resolved
        if rect is not None or len(self._vaos) > 1:
            ctx.copy_framebuffer(resolved, self.target)
        resolved.scissor = rect
        resolved.use()
        self._aliased.use(location=2)
        if len(self._vaos) == 1:
            self._vaos[0].render(moderngl.TRIANGLES, vertices=3)
        else:
            mark, blur = self._vaos
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = "1"  # always: the mark pass writes 0 on edges, 1 elsewhere
            resolved.color_mask = (False, False, False, False)
            mark.render(moderngl.TRIANGLES, vertices=3)
            resolved.color_mask = (True, True, True, True)
            resolved.depth_mask = False
            ctx.depth_func = ">"  # the blur triangle at depth 0.5 passes over the marks only
            blur.render(moderngl.TRIANGLES, vertices=3)
            resolved.depth_mask = True
            ctx.depth_func = "<"
            ctx.disable(moderngl.DEPTH_TEST)
        resolved.scissor = None

    def character_rect(self, box: np.ndarray, view_proj_gl: np.ndarray, margin_px: float) -> tuple[int, int, int, int]:
        """(x, y, width, height) [px] of the framebuffer that holds the world box (2, 3) [min,
        max] projected by view_proj_gl (4, 4) column-major, plus margin_px and FXAA's margin;
        the whole frame when a corner lies behind the camera."""
        corners = self._corners
        corners[:, 0] = box[[0, 1, 0, 1, 0, 1, 0, 1], 0]
        corners[:, 1] = box[[0, 0, 1, 1, 0, 0, 1, 1], 1]
        corners[:, 2] = box[[0, 0, 0, 0, 1, 1, 1, 1], 2]
        np.matmul(corners, view_proj_gl, out=self._clip)  # rows: clip coordinates
        w = self._clip[:, 3]
        if not np.all(w > 1e-6):  # a corner behind the camera: filter the whole frame
            return (0, 0, self.width, self.height)
        ndc = self._clip[:, :2] / w[:, None]
        margin = FXAA_MARGIN_PX + margin_px
        x0 = max(0, int(np.floor((ndc[:, 0].min() * 0.5 + 0.5) * self.width - margin)))
        x1 = min(self.width, int(np.ceil((ndc[:, 0].max() * 0.5 + 0.5) * self.width + margin)))
        y0 = max(0, int(np.floor((ndc[:, 1].min() * 0.5 + 0.5) * self.height - margin)))
        y1 = min(self.height, int(np.ceil((ndc[:, 1].max() * 0.5 + 0.5) * self.height + margin)))
        return (x0, y0, max(0, x1 - x0), max(0, y1 - y0))
