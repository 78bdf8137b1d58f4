"""Antialias policy: which mode a GL gets, and how dense a live loop's drawn mesh may be.

'auto' is MSAA on a hardware GL and FXAA on a software rasterizer (Mesa llvmpipe), where MSAA
triples the mesh pass and FXAA costs about 2.5 ms of CPU at 640x480.
"""

from __future__ import annotations

from puppet.render.errors import RenderError

ANTIALIAS = ("auto", "msaa", "fxaa", "none")
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "lavapipe")
#: A live loop on a software rasterizer draws at most one triangle per this many pixels of its
#: frame (25 600 at 640x480; the critter has 49 816): see puppet.render.lod.
LIVE_PIXELS_PER_TRIANGLE = 12


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
