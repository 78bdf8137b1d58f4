"""What the live view (``puppet.view``) and the Blender link (``puppet.link``) share as network
servers: where they listen and who may connect (``address``: ``[HOST:]PORT``, the socket, the
token), and what one client may cost the others (``guard``: rate limits, merged notices, a
bounded JSON parse). Imports nothing of either.
"""
