"""The live view: watch the character in a browser while performing, and drag point handles.

    view = View("127.0.0.1:8765")        # binds at once (a taken port is an AddressError)
    view.attach(pipeline, source=source)  # serves the page at view.url
    run_live(pipeline, source, view=view)

Address, token and flood guard: ``puppet.net`` (shared with the Blender link). Modules:
protocol (frame header, limits, the default port), orbit
(camera), handles (point handles, drag geometry), encoder (JPEG thread, latest-wins slot),
server (aiohttp: page, sockets, credit), sources (rest pose, take playback), onion (ghosts of a
shot's keys over the frames), view (the loop's side: a facade over its parts: input (page input
routed to the parts), cameras, handle_desk (pick, grab, drag), recording (record button, marks),
playback, key_poses (keys and onion skins), frames (what is rendered for whom), panel). The page and its script are in ``static/`` (no CDN, no build step).
"""

from puppet.view.errors import ViewError
from puppet.view.protocol import DEFAULT_PORT
from puppet.view.sources import RestSource, TakeSource
from puppet.view.view import View

__all__ = ["DEFAULT_PORT", "RestSource", "TakeSource", "View", "ViewError"]
