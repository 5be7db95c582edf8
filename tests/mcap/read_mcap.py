#!/usr/bin/env python3
"""Independent check of an MCAP file with Foxglove's reference Python reader (PyPI `mcap`).

Usage: read_mcap.py FILE.mcap
Prints one JSON object: every channel with its schema, encodings and message count, the
metadata records, whether the file ended cleanly (footer and end magic) and, if not, the
reader's error. Streams the records, so a file cut short (writer killed) is read up to the
last complete chunk, as a person would recover it.
"""
import json
import sys

from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader


def main(path):
    schemas, channels, counts, metadata = {}, {}, {}, {}
    first_json_error = None
    complete = False
    error = None
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False, emit_chunks=False, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    counts[rec.channel_id] = counts.get(rec.channel_id, 0) + 1
                    ch = channels.get(rec.channel_id)
                    if ch is not None and ch.message_encoding == "json" and first_json_error is None:
                        try:
                            json.loads(rec.data)
                        except ValueError as e:
                            first_json_error = f"{ch.topic}: {e}"
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Footer):
                    complete = True
        except Exception as e:  # the reader's own error on a cut file
            error = f"{type(e).__name__}: {e}"
    out = {
        "channels": {
            ch.topic: {
                "schema": schemas[ch.schema_id].name if ch.schema_id in schemas else None,
                "schema_encoding": schemas[ch.schema_id].encoding if ch.schema_id in schemas else None,
                "schema_is_json": _is_json(schemas[ch.schema_id].data) if ch.schema_id in schemas else False,
                "message_encoding": ch.message_encoding,
                "messages": counts.get(cid, 0),
            }
            for cid, ch in channels.items()
        },
        "metadata": metadata,
        "complete": complete,
        "error": error,
        "json_error": first_json_error,
    }
    print(json.dumps(out))


def _is_json(b):
    try:
        json.loads(b)
        return True
    except ValueError:
        return False


if __name__ == "__main__":
    main(sys.argv[1])
