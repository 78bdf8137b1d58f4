"""The renderer's passes, each owning the GL objects it makes and releasing them (``release()``).

mesh (skinning by transform feedback, the lit mesh, the character's bounds), ground (backdrop,
contact shadow), bones (skeleton overlay), antialias (the frame targets, MSAA resolve or FXAA,
and the antialias policy), picking (which triangle lies under a pixel). ``Renderer`` builds
them in that order and orchestrates a frame; a pass whose construction fails releases what it
made, and the renderer releases the passes it had built.
"""
