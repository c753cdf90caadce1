// An independent reader of farsight recordings: the official @mcap/core
// stream reader (zstd chunks through fzstd) reads every record; each
// Foxglove channel's messages (protobuf or JSON; farsight's own
// `farsight-wire` channels are left alone) are decoded with the schema the
// file carries and validated against the official @foxglove/schemas JSON
// schemas, and every frame id a message names must have a transform on
// /tf (as the Foxglove app needs to place it).
//
// usage: node mcap.mjs FILE.mcap --report out.json
//
// Prints the per-channel table; exits 0 when every message is valid and
// every frame id has a transform, else 1.

import { McapStreamReader } from "@mcap/core";
import { decompress } from "fzstd";
import { readFileSync, writeFileSync } from "node:fs";
import { channelReport, decoderFor, validatorFor, shorten } from "./validate.mjs";

const args = process.argv.slice(2);
const file = args[0];
const i = args.indexOf("--report");
const reportPath = i >= 0 ? args[i + 1] : null;

const reader = new McapStreamReader({
  decompressHandlers: { zstd: (buf) => decompress(buf) },
  validateCrcs: true,
});
reader.append(readFileSync(file));

const schemaById = new Map();
const channels = new Map(); // id -> state
const framesUsed = new Set();
const framesKnown = new Set();
let farsightMessages = 0;

function collectFrames(v) {
  if (Array.isArray(v)) return v.forEach(collectFrames);
  if (v && typeof v === "object") {
    for (const [k, x] of Object.entries(v)) {
      if (k === "frame_id" && typeof x === "string" && x) framesUsed.add(x);
      else collectFrames(x);
    }
  }
}

for (let r; (r = reader.nextRecord()); ) {
  if (r.type === "Schema") {
    schemaById.set(r.id, r);
  } else if (r.type === "Channel") {
    // The summary section repeats every channel record.
    if (channels.has(r.id)) continue;
    const schema = schemaById.get(r.schemaId);
    const state = {
      topic: r.topic,
      encoding: r.messageEncoding,
      schemaName: schema?.name ?? "",
      messages: 0,
      valid: 0,
      bytes: 0,
      firstError: null,
      last: null,
    };
    if (r.messageEncoding === "protobuf" || r.messageEncoding === "json") {
      try {
        const channel = {
          topic: r.topic,
          encoding: r.messageEncoding,
          schemaName: schema.name,
          schemaEncoding: schema.encoding,
          schema: schema.data,
        };
        state.decode = decoderFor(channel);
        state.validate = validatorFor(channel);
      } catch (e) {
        state.firstError = `channel: ${e.message}`;
      }
      channels.set(r.id, state);
    }
  } else if (r.type === "Message") {
    const s = channels.get(r.channelId);
    if (!s) {
      farsightMessages += 1;
      continue;
    }
    s.messages += 1;
    s.bytes += r.data.byteLength;
    if (!s.decode) continue;
    try {
      const msg = s.decode(r.data);
      const error = s.validate(msg);
      if (error === null) s.valid += 1;
      else s.firstError ??= error;
      if (s.topic === "/tf") {
        for (const t of msg.transforms ?? []) {
          framesKnown.add(t.parent_frame_id);
          framesKnown.add(t.child_frame_id);
        }
      } else {
        collectFrames(msg);
      }
      s.last = shorten(msg);
    } catch (e) {
      s.firstError ??= `decode: ${e.message}`;
    }
  }
}

const rows = [...channels.values()].sort((a, b) => a.topic.localeCompare(b.topic));
console.log(`${"topic".padEnd(34)} ${"schema".padEnd(28)} ${"msgs".padStart(7)} ${"valid".padStart(7)} ${"MB".padStart(8)}`);
let ok = reader.done();
if (!ok) console.log(`the file ends mid-record (${reader.bytesRemaining()} bytes left over)`);
const report = { file, complete: reader.done(), farsight_messages: farsightMessages, channels: {} };
for (const s of rows) {
  console.log(
    `${s.topic.padEnd(34)} ${s.schemaName.padEnd(28)} ${String(s.messages).padStart(7)} ${String(s.valid).padStart(7)} ${(s.bytes / 1e6).toFixed(3).padStart(8)}`,
  );
  if (s.firstError) console.log(`  first error: ${s.firstError}`);
  ok &&= s.messages === s.valid && !s.firstError;
  report.channels[s.topic] = channelReport(s);
}
const missing = [...framesUsed].filter((f) => !framesKnown.has(f)).sort();
report.frames_used = [...framesUsed].sort();
report.frames_without_transform = missing;
console.log(`frame ids: ${report.frames_used.join(", ")}; without a transform: ${missing.join(", ") || "none"}`);
ok &&= missing.length === 0 && rows.length > 0;
if (reportPath) writeFileSync(reportPath, JSON.stringify(report, null, 1));
process.exit(ok ? 0 : 1);
