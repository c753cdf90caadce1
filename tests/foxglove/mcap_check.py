"""A second independent reader of farsight recordings, in Python.

The official `mcap` package's stream reader reads every record (zstd and
lz4 chunks, CRCs checked); each Foxglove channel's messages are decoded with
the schema the file carries (protobuf through `mcap-protobuf-support`, with
the FileDescriptorSet of the channel's schema record, or JSON) and validated
with `jsonschema` against the official Foxglove JSON schemas, those the
pinned `@foxglove/schemas` npm package ships (read from its generated
module, not copied; farsight's own JSON channels against the JSON schema
they carry). farsight's `farsight-wire` channels are counted, not decoded.
Every frame id a message names must have a transform on a
foxglove.FrameTransforms channel (/tf), as the Foxglove app needs to place it.

usage: python mcap_check.py FILE.mcap [--report out.json] [--schemas index.js]

Prints the per-channel table and writes a report shaped as mcap.mjs's;
exits 0 when every message is valid and every frame id has a transform,
1 otherwise, 2 on bad usage (a missing file, no schemas).

Installed, pinned, by `cargo xtask setup` / `cargo xtask test` into
tests/foxglove/.venv (requirements.txt).
"""

import argparse
import base64
import json
import math
import re
import sys
from pathlib import Path

from google.protobuf.descriptor import FieldDescriptor
from jsonschema import Draft7Validator
from jsonschema.validators import validator_for
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

HERE = Path(__file__).resolve().parent
DEFAULT_SCHEMAS = HERE / "node_modules/@foxglove/schemas/dist/jsonschema/index.js"

# Time in the Foxglove schemas is {sec, nsec}; protobuf carries it as
# google.protobuf.Timestamp / Duration {seconds, nanos}.
TIME_TYPES = ("google.protobuf.Timestamp", "google.protobuf.Duration")


def official_schemas(path):
    """The official JSON schemas by short name (CompressedImage, ...), from
    @foxglove/schemas' generated CommonJS module: each is
    `exports.NAME = {JSON};`, and aliases `exports.A = exports.B;`."""
    text = path.read_text(encoding="utf-8")
    schemas = {
        name: json.loads(body)
        for name, body in re.findall(
            r"^exports\.(\w+) = (\{.*?^\});$", text, re.MULTILINE | re.DOTALL
        )
    }
    for alias, name in re.findall(r"^exports\.(\w+) = exports\.(\w+);$", text, re.MULTILINE):
        if name in schemas:
            schemas[alias] = schemas[name]
    if not schemas:
        raise ValueError(f"{path}: no `exports.NAME = {{...}};` schema found")
    return schemas


def to_foxglove_json(msg):
    """A protobuf message as the JSON Foxglove's schemas describe, the shape
    the npm reader gets from protobufjs (defaults included, enums as numbers,
    bytes as base64, unset sub-messages as null): time as {sec, nsec}."""
    if msg.DESCRIPTOR.full_name in TIME_TYPES:
        return {"sec": msg.seconds, "nsec": msg.nanos}
    out = {}
    for field in msg.DESCRIPTOR.fields:
        value = getattr(msg, field.name)
        is_message = field.type in (FieldDescriptor.TYPE_MESSAGE, FieldDescriptor.TYPE_GROUP)
        if field.is_repeated:
            out[field.name] = [scalar_or_message(field, v) for v in value]
        elif is_message and not msg.HasField(field.name):
            out[field.name] = None
        else:
            out[field.name] = scalar_or_message(field, value)
    return out


def scalar_or_message(field, value):
    if field.type in (FieldDescriptor.TYPE_MESSAGE, FieldDescriptor.TYPE_GROUP):
        return to_foxglove_json(value)
    if field.type == FieldDescriptor.TYPE_BYTES:
        return base64.b64encode(value).decode("ascii")
    return value


def shorten(v):
    """Large byte fields and arrays shortened, for reports (as validate.mjs);
    non-finite numbers as null (JSON has none)."""
    if isinstance(v, list):
        return f"[{len(v)} items]" if len(v) > 64 else [shorten(x) for x in v]
    if isinstance(v, str) and len(v) > 256:
        return f"<{len(v)} chars>"
    if isinstance(v, dict):
        return {k: shorten(x) for k, x in v.items()}
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def first_error(validator, msg):
    """The schema error at the shallowest place, or None when valid."""
    errors = sorted(validator.iter_errors(msg), key=lambda e: (len(e.absolute_path), str(e.message)))
    if not errors:
        return None
    e = errors[0]
    where = "/".join(str(p) for p in e.absolute_path)
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"/{where}: {e.message[:300]}{more}"


def collect_frames(v, out):
    if isinstance(v, list):
        for x in v:
            collect_frames(x, out)
    elif isinstance(v, dict):
        for k, x in v.items():
            if k == "frame_id" and isinstance(x, str):
                if x:
                    out.add(x)
            else:
                collect_frames(x, out)


class ChannelState:
    def __init__(self, channel, schema):
        self.topic = channel.topic
        self.encoding = channel.message_encoding
        self.schema_name = schema.name if schema else ""
        self.messages = 0
        self.valid = 0
        self.bytes = 0
        self.first_error = None
        self.last = None
        self.decode = None
        self.validator = None
        self.transforms = self.schema_name == "foxglove.FrameTransforms"

    def note(self, error):
        if self.first_error is None:
            self.first_error = error

    def report(self):
        return {
            "schema": self.schema_name,
            "encoding": self.encoding,
            "messages": self.messages,
            "valid": self.valid,
            "bytes": self.bytes,
            "first_error": self.first_error,
            "last": self.last,
        }


def prepare(state, channel, schema, schemas, protobuf):
    """Sets the channel's decoder and validator, or its first error."""
    if schema is None:
        state.note(f"channel: schema id {channel.schema_id} has no schema record")
        return
    if channel.message_encoding == "json":
        state.decode = lambda data: json.loads(data)
        try:
            doc = json.loads(schema.data)
            cls = validator_for(doc, default=Draft7Validator)
            cls.check_schema(doc)
            state.validator = cls(doc)
        except Exception as e:  # noqa: BLE001 - reported per channel
            state.note(f"channel: the JSON schema {schema.name} it carries: {e}")
        return
    if schema.encoding != "protobuf":
        state.note(f"channel: unexpected encoding {channel.message_encoding}/{schema.encoding}")
        return
    short = schema.name.removeprefix("foxglove.")
    if short not in schemas or not schema.name.startswith("foxglove."):
        state.note(f"channel: no official schema for {schema.name}")
        return
    state.validator = Draft7Validator(schemas[short])
    try:
        decoder = protobuf.decoder_for(channel.message_encoding, schema)
    except Exception as e:  # noqa: BLE001
        state.note(f"channel: the FileDescriptorSet of {schema.name}: {e}")
        return
    state.decode = lambda data: to_foxglove_json(decoder(data))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--report", type=Path)
    parser.add_argument("--schemas", type=Path, default=DEFAULT_SCHEMAS,
                        help="@foxglove/schemas' dist/jsonschema/index.js")
    args = parser.parse_args()
    if not args.file.is_file():
        print(f"{args.file}: no such file", file=sys.stderr)
        return 2
    try:
        schemas = official_schemas(args.schemas)
    except (OSError, ValueError) as e:
        print(f"the official Foxglove schemas: {e} (npm ci in tests/foxglove installs them)", file=sys.stderr)
        return 2

    protobuf = DecoderFactory()
    schema_by_id = {}
    channels = {}  # id -> ChannelState (Foxglove channels only)
    seen_channels = set()
    frames_used, frames_known = set(), set()
    farsight_messages = 0
    complete, read_error = True, None
    try:
        with open(args.file, "rb") as f:
            for r in StreamReader(f, validate_crcs=True).records:
                if isinstance(r, Schema):
                    schema_by_id[r.id] = r
                elif isinstance(r, Channel):
                    # The summary section repeats every channel record.
                    if r.id in seen_channels:
                        continue
                    seen_channels.add(r.id)
                    if r.message_encoding not in ("protobuf", "json"):
                        continue
                    schema = schema_by_id.get(r.schema_id)
                    state = ChannelState(r, schema)
                    prepare(state, r, schema, schemas, protobuf)
                    channels[r.id] = state
                elif isinstance(r, Message):
                    s = channels.get(r.channel_id)
                    if s is None:
                        farsight_messages += 1
                        continue
                    s.messages += 1
                    s.bytes += len(r.data)
                    if s.decode is None or s.validator is None:
                        continue
                    try:
                        msg = s.decode(r.data)
                    except Exception as e:  # noqa: BLE001
                        s.note(f"decode: {e}")
                        continue
                    error = first_error(s.validator, msg)
                    if error is None:
                        s.valid += 1
                    else:
                        s.note(error)
                    if s.transforms:
                        for t in msg.get("transforms") or []:
                            frames_known.add(t.get("parent_frame_id"))
                            frames_known.add(t.get("child_frame_id"))
                    else:
                        collect_frames(msg, frames_used)
                    s.last = shorten(msg)
    except Exception as e:  # noqa: BLE001 - a truncated or corrupt file
        complete, read_error = False, f"{type(e).__name__}: {str(e) or 'the file ends mid-record'}"

    rows = sorted(channels.values(), key=lambda s: s.topic)
    print(f"{'topic':<34} {'schema':<28} {'msgs':>7} {'valid':>7} {'MB':>8}")
    ok = complete
    if read_error:
        print(f"the file could not be read to its end: {read_error}")
    report = {
        "file": str(args.file),
        "reader": "python mcap (StreamReader) + mcap-protobuf-support + jsonschema",
        "complete": complete,
        "read_error": read_error,
        "farsight_messages": farsight_messages,
        "channels": {},
    }
    for s in rows:
        print(f"{s.topic:<34} {s.schema_name:<28} {s.messages:>7} {s.valid:>7} {s.bytes / 1e6:>8.3f}")
        if s.first_error:
            print(f"  first error: {s.first_error}")
        ok = ok and s.messages == s.valid and s.first_error is None
        report["channels"][s.topic] = s.report()
    missing = sorted(frames_used - frames_known)
    report["frames_used"] = sorted(frames_used)
    report["frames_without_transform"] = missing
    print(
        f"frame ids: {', '.join(report['frames_used'])}; "
        f"without a transform: {', '.join(missing) or 'none'}"
    )
    ok = ok and not missing and bool(rows)
    if args.report:
        args.report.write_text(json.dumps(report, indent=1), encoding="utf-8")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
