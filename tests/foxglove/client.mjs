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

import { connect, option } from "./connect.mjs";
import { channelReport, decoderFor, validatorFor, shorten } from "./validate.mjs";
import { writeFileSync } from "node:fs";

const args = process.argv.slice(2);
const url = args[0];
const opt = (name, dflt) => option(args, name, dflt);
const untilMessages = Number(opt("--until-messages", "5"));
const timeoutS = Number(opt("--timeout-s", "60"));
const required = (opt("--require", "") || "").split(",").filter((t) => t);
const reportPath = opt("--report", null);

const channels = new Map(); // id -> state
const bySub = new Map();
const client = connect(url);
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
      // ws-protocol sends a protobuf schema base64-encoded, JSON as text.
      const schema =
        ch.schemaEncoding === "protobuf" ? Buffer.from(ch.schema, "base64") : new TextEncoder().encode(ch.schema);
      const channel = { ...ch, schema };
      state.decode = decoderFor(channel);
      state.validate = validatorFor(channel);
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
    const error = s.validate(msg);
    if (error === null) {
      s.valid += 1;
    } else {
      s.firstError ??= error;
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
    report.channels[s.topic] = channelReport(s, { capture_hz: hz, receive_span_s: recvS });
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
