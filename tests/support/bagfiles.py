"""Bags as dockhil recorded them before json channels: msgpack messages, written with
the reference MCAP writer, so that reading and converting old bags is tested on bags
that dockhil's own writer did not make."""

from __future__ import annotations

import json

from mcap.writer import CompressionType, Writer

from dockhil.msgs import TYPES
from dockhil.msgs.codec import schema


def write_msgpack_bag(path, topics: dict[str, str], messages, *, per_chunk: int = 50) -> None:
    """topics: topic -> type name; messages: (topic, log_time_ns, publish_time_ns, wire bytes)."""
    with open(path, "wb") as fh:
        writer = Writer(fh, chunk_size=2**62, compression=CompressionType.ZSTD)
        writer.start(profile="", library="dockhil 0.1.0")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        sequence: dict[str, int] = {}
        for topic, type_name in topics.items():
            if type_name not in schemas:
                data = json.dumps(schema(TYPES[type_name]), separators=(",", ":")).encode()
                schemas[type_name] = writer.register_schema(name=type_name, encoding="jsonschema", data=data)
            channels[topic] = writer.register_channel(
                topic=topic, message_encoding="msgpack", schema_id=schemas[type_name]
            )
            sequence[topic] = 0
        for k, (topic, log_ns, publish_ns, data) in enumerate(messages):
            writer.add_message(channels[topic], log_ns, data, publish_ns, sequence[topic])
            sequence[topic] += 1
            if k % per_chunk == per_chunk - 1:
                writer.flush()
        writer.finish()


def assert_messages_meet_their_channel_schemas(path) -> int:
    """Read `path` with the reference MCAP reader and validate every message, as JSON,
    against its channel's JSON Schema (the jsonschema package); returns how many."""
    import jsonschema
    from mcap.reader import make_reader

    validators: dict[int, jsonschema.Draft202012Validator] = {}
    n = 0
    with open(path, "rb") as fh:
        for schema_rec, channel, message in make_reader(fh, validate_crcs=True).iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema_rec.encoding == "jsonschema", channel
            validator = validators.get(schema_rec.id)
            if validator is None:
                found = json.loads(schema_rec.data)
                assert found["type"] == "object" and "$ref" not in found, schema_rec.name
                validator = validators[schema_rec.id] = jsonschema.Draft202012Validator(found)
            validator.validate(json.loads(message.data))
            n += 1
    return n
