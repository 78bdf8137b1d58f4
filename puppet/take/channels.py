"""Which of a take's channels is which: by its topic name, or by its schema when a damaged name
is none of the take's, so that one flipped byte in a topic name loses no channel.

    topic = channel_topic(channel.topic, schemas.get(channel.schema_id))  # fmt.TOPIC, KEY_TOPIC, ...

A channel whose name and schema are both damaged is left to its content: the readings' checksums
(``puppet.take.reader``) and the keys' (``puppet.take.keys``).
"""

from __future__ import annotations


def _known() -> dict[str, tuple[str, tuple[bytes, ...]]]:
    """{topic: (schema name, schema texts)} of every channel a take may hold."""
    from puppet.take import format as fmt
    from puppet.take import keys, markers

    return {fmt.TOPIC: (fmt.SCHEMA_NAME, tuple(t.encode() for t in fmt.SCHEMA_TEXTS.values())),
            keys.KEY_TOPIC: (keys.KEY_SCHEMA_NAME, (keys.KEY_SCHEMA.encode(),)),
            markers.MARKER_TOPIC: (markers.MARKER_SCHEMA_NAME, (markers.MARKER_SCHEMA.encode(),))}


def channel_topic(topic: str, schema) -> str | None:
    """The take topic a channel carries: its own name when that is one of the take's topics,
    else the topic whose schema it refers to (``schema``: an mcap Schema record or None; known by
    its name or by its text, one of them may be damaged too). None: another tool's channel."""
    known = _known()
    if topic in known:
        return topic
    if schema is None:
        return None
    for name, (schema_name, texts) in known.items():
        if schema.name == schema_name or bytes(schema.data) in texts:
            return name
    return None


def renamed(topic: str, found: str) -> str:
    """The note for a channel recognised by its schema: its damaged name and what it is."""
    return f"channel {topic!r} is {found} by its schema (its topic name is damaged)"
