// The Foxglove app's publishing side, played by the official
// @foxglove/ws-protocol client: it advertises client channels (JSON, as the
// app's 3-D panel, Teleop and Publish panels do) and publishes one message
// on each every --every-ms, collecting the server's status messages.
//
// usage: node publish.mjs ws://127.0.0.1:8765 --publish TOPIC SCHEMA JSON [--publish ...]
//          [--every-ms 100] [--until-statuses N] [--timeout-s S] --report out.json
//
// Stops once the server has sent N error statuses (the refusals), exit 0,
// or at the timeout, exit 2; SIGTERM stops it too, exit 0 (the caller
// decides when the robot has seen enough). Exits 3 at once when the server
// does not offer client publishing. The report: the server's capabilities,
// the statuses, messages sent per topic.

import { connect, option } from "./connect.mjs";
import { writeFileSync } from "node:fs";

const args = process.argv.slice(2);
const url = args[0];
const opt = (name, dflt) => option(args, name, dflt);
const publish = [];
args.forEach((a, i) => {
  if (a === "--publish") publish.push({ topic: args[i + 1], schemaName: args[i + 2], json: args[i + 3] });
});
const everyMs = Number(opt("--every-ms", "100"));
const untilStatuses = Number(opt("--until-statuses", "0"));
const timeoutS = Number(opt("--timeout-s", "60"));
const reportPath = opt("--report", null);

const client = connect(url);
const report = { capabilities: null, statuses: [], sent: {} };
let timer = null;

function finish(code) {
  if (timer) clearInterval(timer);
  if (reportPath) writeFileSync(reportPath, JSON.stringify(report, null, 2));
  console.log(`sent ${JSON.stringify(report.sent)}; ${report.statuses.length} statuses`);
  for (const s of report.statuses) console.log(`status ${s.level}: ${s.message}`);
  process.exit(code);
}

process.on("SIGTERM", () => finish(0));
setTimeout(() => finish(2), timeoutS * 1000);

client.on("error", (e) => {
  console.error(`client error: ${e?.message ?? e}`);
  finish(4);
});
client.on("status", (s) => {
  report.statuses.push({ level: s.level, message: s.message });
  // Level 2 is an error in the ws-protocol spec.
  if (untilStatuses > 0 && report.statuses.filter((x) => x.level === 2).length >= untilStatuses) finish(0);
});
client.on("serverInfo", (info) => {
  report.capabilities = info.capabilities;
  if (!info.capabilities.includes("clientPublish")) {
    console.log(`the server offers no client publishing: ${JSON.stringify(info.capabilities)}`);
    finish(3);
  }
  const channels = publish.map((p) => ({
    ...p,
    id: client.advertise({ topic: p.topic, encoding: "json", schemaName: p.schemaName }),
    bytes: new TextEncoder().encode(p.json),
  }));
  timer = setInterval(() => {
    for (const c of channels) {
      client.sendMessage(c.id, c.bytes);
      report.sent[c.topic] = (report.sent[c.topic] ?? 0) + 1;
    }
  }, everyMs);
});
