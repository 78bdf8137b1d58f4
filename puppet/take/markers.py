"""Named time marks in a take: an extra MCAP channel next to the readings.

A mark is one JSON message ``{"t_ns": int, "name": str}`` on channel ``/puppet/markers``
(schema ``puppet.Marker``, jsonschema); log_time = the reading time it marks. Readers that know
only the readings channel skip it, so takes with marks stay readable by every puppet version.
"""

from __future__ import annotations

import json
from pathlib import Path

from puppet.take.errors import TakeError

MARKER_TOPIC = "/puppet/markers"
MARKER_SCHEMA_NAME = "puppet.Marker"
MARKER_SCHEMA_ENCODING = "jsonschema"
MARKER_SCHEMA = json.dumps({
    "type": "object",
    "properties": {"t_ns": {"type": "integer"}, "name": {"type": "string"}},
    "required": ["t_ns", "name"],
})
MARKER_MESSAGE_ENCODING = "json"
MAX_NAME = 200


def encode_marker(t_ns: int, name: str) -> bytes:
    name = str(name)
    if not 0 < len(name) <= MAX_NAME:
        raise ValueError(f"marker name must be 1..{MAX_NAME} characters, got {len(name)}")
    return json.dumps({"t_ns": int(t_ns), "name": name}).encode()


def read_markers(path) -> list[tuple[int, str]]:
    """[(t_ns, name)] of a take's marks in file order (a take killed mid-write included)."""
    from mcap.exceptions import McapError
    from mcap.stream_reader import StreamReader
    from mcap.records import Channel, Message, Schema

    from puppet.take.channels import channel_topic

    path = Path(path)
    marks, channel, schemas = [], None, {}
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, skip_magic=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif (isinstance(record, Channel) and channel is None
                      and channel_topic(record.topic, schemas.get(record.schema_id)) == MARKER_TOPIC):
                    channel = record.id
                elif isinstance(record, Message) and channel is not None and record.channel_id == channel:
                    try:
                        item = json.loads(record.data)
                        marks.append((int(item["t_ns"]), str(item["name"])))
                    except (ValueError, KeyError, TypeError):
                        continue  # a corrupt mark loses only itself
    except (McapError, EOFError, ValueError):
        pass  # a truncated tail: the marks before it stand
    except OSError as err:
        raise TakeError(path, f"cannot read marks: {err.strerror}") from err
    return marks
