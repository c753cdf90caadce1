#!/usr/bin/env bash
# Removes what deploy/install.sh installed (run as root). Stage configs in
# /etc/farsight and recordings in /var/lib/farsight are kept unless --purge.
#
#   sudo deploy/uninstall.sh [--purge] [--prefix DIR] [--dry-run]
set -euo pipefail
prefix="" purge=0 dry=0
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix="$2"; shift 2 ;;
    --purge) purge=1; shift ;;
    --dry-run) dry=1; shift ;;
    -h|--help) sed -n '2,6p' "$0"; exit 0 ;;
    *) echo "uninstall.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
stages="camera-ingest inference bin-projection costmap-fusion subgoal-selection velocity-servoing command-mux bridge"
say() { echo "uninstall: $*"; }
act() { say "$*"; [ "$dry" = 1 ] || "$@"; }
if [ -z "$prefix" ]; then
  act systemctl disable --now farsight.target || true
  for s in $stages; do act systemctl stop "farsight-$s.service" || true; done
fi
for s in $stages; do
  act rm -f "$prefix/usr/local/bin/farsight-$s" "$prefix/etc/systemd/system/farsight-$s.service"
done
act rm -f "$prefix/usr/local/bin/farsight" "$prefix/etc/systemd/system/farsight.target" \
  "$prefix/usr/lib/tmpfiles.d/farsight.conf"
act rm -rf "$prefix/usr/local/lib/farsight" "$prefix/usr/local/share/farsight" "$prefix/usr/local/share/doc/farsight"
if [ "$purge" = 1 ]; then
  act rm -rf "$prefix/etc/farsight" "$prefix/var/lib/farsight"
  [ -n "$prefix" ] || act userdel farsight || true
else
  say "kept $prefix/etc/farsight (configs) and $prefix/var/lib/farsight; --purge removes them"
fi
[ -n "$prefix" ] || act systemctl daemon-reload
say "done"
