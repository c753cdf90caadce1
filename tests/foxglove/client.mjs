// An independent client of farsight's Foxglove server: the official
// @foxglove/ws-protocol client subscribes to every channel the server
// advertises, decodes each message with the schema the channel advertised
// (protobuf descriptors through protobufjs, or JSON), and validates it
// against the official @foxglove/schemas JSON schemas (farsight's own JSON
// channels against the schema they advertise).
//
// usage: node client.mjs ws://127.0.0.1:8765 --until-messages N --require /a,/b --timeout-s S --report out.json
//
// Stops once each --require topic (default: every channel advertised) has
// N messages, exiting 0, or at the timeout, exiting 2;
// prints the per-channel table and writes the report: per topic, schema,
// messages, schema-valid, first error, bytes, capture-time rate, and the
// newest decoded message (large byte fields shortened).

// CommonJS packages: their exports object is the default import.
import wsProtocol from "@foxglove/ws-protocol";
import { WebSocket } from "ws";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import Ajv from "ajv";
import schemas from "@foxglove/schemas/jsonschema.js";
import { writeFileSync } from "node:fs";

const { FoxgloveClient } = wsProtocol;

const args = process.argv.slice(2);
const url = args[0];
const opt = (name, dflt) => {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : dflt;
};
const untilMessages = Number(opt("--until-messages", "5"));
const timeoutS = Number(opt("--timeout-s", "60"));
const required = (opt("--require", "") || "").split(",").filter((t) => t);
const reportPath = opt("--report", null);

const ajv = new Ajv({ allErrors: true, strict: false });
const validators = new Map();
function validatorFor(channel) {
  const key = `${channel.schemaEncoding}:${channel.schemaName}:${channel.schema}`;
  if (!validators.has(key)) {
    let schema;
    if (channel.encoding === "json") {
      schema = JSON.parse(channel.schema);
    } else {
      const short = channel.schemaName.replace(/^foxglove\./, "");
      schema = schemas[short];
      if (!schema) throw new Error(`no official schema for ${channel.schemaName}`);
    }
    validators.set(key, ajv.compile(schema));
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

function decoderFor(channel) {
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  if (channel.encoding !== "protobuf" || channel.schemaEncoding !== "protobuf") {
    throw new Error(`${channel.topic}: unexpected encoding ${channel.encoding}/${channel.schemaEncoding}`);
  }
  const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
  const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
  return (bytes) =>
    toFoxgloveJson(
      type.toObject(type.decode(bytes), { longs: Number, enums: Number, bytes: String, defaults: true }),
    );
}

function shorten(v) {
  if (Array.isArray(v)) return v.length > 64 ? `[${v.length} items]` : v.map(shorten);
  if (typeof v === "string" && v.length > 256) return `<${v.length} chars>`;
  if (v && typeof v === "object") return Object.fromEntries(Object.entries(v).map(([k, x]) => [k, shorten(x)]));
  return v;
}

const channels = new Map(); // id -> state
const bySub = new Map();
// The foxglove SDK's server names the ws-protocol v1 spec
// "foxglove.sdk.v1" (inline schemas; not "foxglove.sdk.v1.1", whose schema
// tables this client does not read); the npm client speaks that spec and
// names it "foxglove.websocket.v1".
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const started = Date.now();
let serverInfo = null;

client.on("serverInfo", (info) => (serverInfo = info));
client.on("advertise", (list) => {
  for (const ch of list) {
    if (channels.has(ch.id)) continue;
    const state = {
      topic: ch.topic,
      schemaName: ch.schemaName,
      encoding: ch.encoding,
      messages: 0,
      valid: 0,
      bytes: 0,
      firstError: null,
      firstLogNs: null,
      lastLogNs: null,
      firstRecvMs: null,
      lastRecvMs: null,
      last: null,
    };
    try {
      state.decode = decoderFor(ch);
      state.validate = validatorFor(ch);
    } catch (e) {
      state.firstError = `advertise: ${e.message}`;
    }
    channels.set(ch.id, state);
    bySub.set(client.subscribe(ch.id), state);
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const s = bySub.get(subscriptionId);
  if (!s) return;
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  s.messages += 1;
  s.bytes += bytes.byteLength;
  const t = Number(timestamp);
  s.firstLogNs ??= t;
  s.lastLogNs = t;
  s.firstRecvMs ??= Date.now();
  s.lastRecvMs = Date.now();
  if (!s.decode) return;
  try {
    const msg = s.decode(bytes);
    if (s.validate(msg)) {
      s.valid += 1;
    } else {
      s.firstError ??= ajv.errorsText(s.validate.errors);
    }
    s.last = shorten(msg);
  } catch (e) {
    s.firstError ??= `decode: ${e.message}`;
  }
});
client.on("error", (e) => {
  console.error(`client error: ${e?.message ?? e}`);
});

function finish(code) {
  const rows = [...channels.values()].sort((a, b) => a.topic.localeCompare(b.topic));
  const elapsedS = (Date.now() - started) / 1000;
  console.log(
    `${"topic".padEnd(34)} ${"schema".padEnd(26)} ${"msgs".padStart(6)} ${"valid".padStart(6)} ${"Hz".padStart(6)} ${"kB/s".padStart(8)}`,
  );
  let totalBytes = 0;
  const report = { server: serverInfo?.name ?? null, capabilities: serverInfo?.capabilities ?? [], elapsed_s: elapsedS, channels: {} };
  for (const s of rows) {
    const spanS = s.lastLogNs !== null ? (s.lastLogNs - s.firstLogNs) / 1e9 : 0;
    const hz = s.messages > 1 && spanS > 0 ? (s.messages - 1) / spanS : 0;
    const recvS = s.lastRecvMs !== null ? (s.lastRecvMs - s.firstRecvMs) / 1000 : 0;
    totalBytes += s.bytes;
    console.log(
      `${s.topic.padEnd(34)} ${s.schemaName.padEnd(26)} ${String(s.messages).padStart(6)} ${String(s.valid).padStart(6)} ${hz.toFixed(1).padStart(6)} ${(s.bytes / 1000 / Math.max(elapsedS, 1e-3)).toFixed(1).padStart(8)}`,
    );
    if (s.firstError) console.log(`  first error: ${s.firstError}`);
    report.channels[s.topic] = {
      schema: s.schemaName,
      encoding: s.encoding,
      messages: s.messages,
      valid: s.valid,
      bytes: s.bytes,
      capture_hz: hz,
      receive_span_s: recvS,
      first_error: s.firstError,
      last: s.last,
    };
  }
  report.bytes = totalBytes;
  report.bytes_per_s = totalBytes / Math.max(elapsedS, 1e-3);
  console.log(`total ${(totalBytes / 1e6).toFixed(3)} MB in ${elapsedS.toFixed(1)} s: ${(report.bytes_per_s / 1000).toFixed(1)} kB/s`);
  if (reportPath) writeFileSync(reportPath, JSON.stringify(report, null, 1));
  client.close();
  process.exit(code);
}

const timer = setInterval(() => {
  const all = [...channels.values()];
  const count = (topic) => all.find((s) => s.topic === topic)?.messages ?? 0;
  const done = required.length
    ? required.every((t) => count(t) >= untilMessages)
    : all.length > 0 && all.every((s) => s.messages >= untilMessages);
  if (done) {
    clearInterval(timer);
    finish(0);
  } else if (Date.now() - started > timeoutS * 1000) {
    clearInterval(timer);
    console.error(`timeout after ${timeoutS} s`);
    finish(2);
  }
}, 100);
