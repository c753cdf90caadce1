// Decoding and validation shared by the live client (client.mjs) and the
// recording reader (mcap.mjs): each channel's messages decoded with the
// schema it carries (protobuf descriptors through protobufjs, or JSON) and
// validated against the official @foxglove/schemas JSON schemas (farsight's
// own JSON channels against the JSON schema they carry).

import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import Ajv from "ajv";
// CommonJS: its exports object is the default import.
import schemas from "@foxglove/schemas/jsonschema.js";

const ajv = new Ajv({ allErrors: true, strict: false });
const validators = new Map();

// A channel: { topic, encoding ("protobuf" | "json"), schemaName,
// schemaEncoding ("protobuf" | "jsonschema"), schema: Uint8Array }.
export function validatorFor(channel) {
  const text = new TextDecoder().decode(channel.schema);
  const key = `${channel.schemaEncoding}:${channel.schemaName}:${text}`;
  if (!validators.has(key)) {
    let schema;
    if (channel.encoding === "json") {
      schema = JSON.parse(text);
    } else {
      const short = channel.schemaName.replace(/^foxglove\./, "");
      schema = schemas[short];
      if (!schema) throw new Error(`no official schema for ${channel.schemaName}`);
    }
    const validate = ajv.compile(schema);
    validators.set(key, (msg) => (validate(msg) ? null : ajv.errorsText(validate.errors)));
  }
  return validators.get(key);
}

// protobuf -> the JSON shape Foxglove's schemas describe: time as
// {sec, nsec} (protobuf's google.protobuf.Timestamp is {seconds, nanos}).
function toFoxgloveJson(v) {
  if (Array.isArray(v)) return v.map(toFoxgloveJson);
  if (v && typeof v === "object") {
    const keys = Object.keys(v);
    if (keys.length === 2 && "seconds" in v && "nanos" in v) {
      return { sec: v.seconds, nsec: v.nanos };
    }
    return Object.fromEntries(keys.map((k) => [k, toFoxgloveJson(v[k])]));
  }
  return v;
}

export function decoderFor(channel) {
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  if (channel.encoding !== "protobuf" || channel.schemaEncoding !== "protobuf") {
    throw new Error(`${channel.topic}: unexpected encoding ${channel.encoding}/${channel.schemaEncoding}`);
  }
  const set = descriptor.FileDescriptorSet.decode(channel.schema);
  const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
  return (bytes) =>
    toFoxgloveJson(
      type.toObject(type.decode(bytes), { longs: Number, enums: Number, bytes: String, defaults: true }),
    );
}

// Large byte fields and arrays shortened, for reports.
export function shorten(v) {
  if (Array.isArray(v)) return v.length > 64 ? `[${v.length} items]` : v.map(shorten);
  if (typeof v === "string" && v.length > 256) return `<${v.length} chars>`;
  if (v && typeof v === "object") return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, shorten(x)]));
  return v;
}

// One channel's line of a report: what both scripts count per channel.
export function channelReport(s, extra = {}) {
  return {
    schema: s.schemaName,
    encoding: s.encoding,
    messages: s.messages,
    valid: s.valid,
    bytes: s.bytes,
    ...extra,
    first_error: s.firstError,
    last: s.last,
  };
}
