"""The live link: puppet streams each solve to Blender (the add-on in puppet/blender_addon/).

Modules: wire (the versioned protocol, standard library only, shipped inside the add-on), pose
(the glTF export's joint keys and the FAST vertices of a solve), server (the ``Link``: sockets,
latest-wins per client, acks and latency).
"""

from puppet.link.server import DEFAULT_PORT, Link

__all__ = ["DEFAULT_PORT", "Link"]
