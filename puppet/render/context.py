"""A standalone, headless OpenGL 3.3+ context on EGL (a GPU driver or Mesa's llvmpipe)."""

import ctypes.util

import moderngl

from puppet.render.errors import EGL_PACKAGES, RenderError

#: OpenGL version the renderer's shaders need (GLSL 330, uniform blocks, transform feedback).
REQUIRED_GL_VERSION = 330


def _install_hint() -> str:
    return "install the EGL/Mesa packages: sudo apt-get install " + " ".join(EGL_PACKAGES)


def create_context(*, device_index: int = 0) -> moderngl.Context:
    """Create a headless moderngl context on EGL.

    device_index: which EGL device to use (0: the first GPU, or llvmpipe when there is none).
    Raises RenderError naming the system packages to install when EGL or Mesa is missing.
    """
    if ctypes.util.find_library("EGL") is None:
        raise RenderError(f"libEGL not found: {_install_hint()}")
    try:
        ctx = moderngl.create_standalone_context(
            backend="egl", require=REQUIRED_GL_VERSION, device_index=device_index
        )
    # glcontext reports a missing or unusable libEGL / driver with a bare Exception, so this is the
    # narrowest catch available; it re-raises a typed error and keeps the cause.
    except Exception as err:
        raise RenderError(f"cannot create an EGL OpenGL context ({err}): {_install_hint()}") from err
    return ctx


def gl_renderer_name(ctx: moderngl.Context) -> str:
    """The GL_RENDERER string of ctx, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)'."""
    return str(ctx.info["GL_RENDERER"])
