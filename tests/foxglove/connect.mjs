// What the live scripts (client.mjs, publish.mjs) share: their command
// line and the connection to farsight's server.

// CommonJS packages: their exports object is the default import.
import wsProtocol from "@foxglove/ws-protocol";
import { WebSocket } from "ws";

export const { FoxgloveClient } = wsProtocol;

// `--name value` from the command line, or the default.
export function option(args, name, dflt) {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : dflt;
}

// The official client on `url`. The foxglove SDK's server names the
// ws-protocol v1 spec "foxglove.sdk.v1" (inline schemas; not
// "foxglove.sdk.v1.1", whose schema tables this client does not read); the
// npm client speaks that spec and names it "foxglove.websocket.v1".
export function connect(url) {
  const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  return new FoxgloveClient({ ws });
}
