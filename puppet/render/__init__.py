"""Offscreen moderngl renderer with skinning in the vertex shader, and frame sinks.

    from puppet.render import Renderer, VideoSink
    with Renderer(V, F, W, width=640, height=480) as renderer, VideoSink("take.mp4", 30) as video:
        video.write(renderer.draw(T))      # T: (4m, 3) float32 handle transforms

Modules: context (EGL context, RenderError with the packages to install), camera (Camera,
automatic framing), skin_weights (W packed for the shader, exact), clusters (vertices grouped
by place), bounds (a box of the skinned mesh from T alone), overlay (bone states and colors),
shaders (GLSL), passes (mesh, ground and contact shadow, bones, antialias, picking: each owns
its GL objects), renderer (Renderer, which orchestrates them), sinks (PngSink, VideoSink). On llvmpipe, MSAA (samples=4, the default) costs about as much as
the rest of the frame; Renderer(..., samples=0, fxaa=True) antialiases for a fraction of that.
"""

from puppet.render.camera import Camera
from puppet.render.context import create_context
from puppet.render.errors import EGL_PACKAGES, RenderError, RenderInputError, SinkError
from puppet.render.overlay import BONE_STATE_COLORS
from puppet.render.renderer import SKINNING_MODES, Renderer
from puppet.render.sinks import PngSink, VideoSink
from puppet.render.skin_weights import lbs_matrix, pack_weights

__all__ = [
    "BONE_STATE_COLORS",
    "Camera",
    "EGL_PACKAGES",
    "PngSink",
    "RenderError",
    "RenderInputError",
    "Renderer",
    "SKINNING_MODES",
    "SinkError",
    "VideoSink",
    "create_context",
    "lbs_matrix",
    "pack_weights",
]
