"""A second program holding a session: opens FOLDER as its writer, prints 'ready', waits for
stdin to close (or to be killed)."""

import sys

from puppet.studio import SessionWriter

session = SessionWriter.open(sys.argv[1])
print("ready", flush=True)
sys.stdin.read()
session.close()
