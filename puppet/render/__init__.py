"""Offscreen moderngl renderer with skinning in the vertex shader, and frame sinks."""
