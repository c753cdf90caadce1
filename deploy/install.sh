#!/usr/bin/env bash
# Installs farsight on the robot computer (run as root), or stages the files
# under a prefix for packaging. Prints every action; --dry-run only prints.
#
#   sudo deploy/install.sh                    # build, install, enable farsight.target
#   deploy/install.sh --prefix /tmp/stage --bin-dir target/release   # stage, no root needed
#   deploy/install.sh --dry-run               # what it would do
#
# Options:
#   --prefix DIR    install under DIR (no user, no systemctl: staging)
#   --bin-dir DIR   copy the binaries from DIR instead of building them
#   --ort-lib FILE  ONNX Runtime's libonnxruntime.so (default: $ORT_DYLIB_PATH,
#                   else what `cargo xtask setup` fetched)
#   --models DIR    the ONNX models folder (default: ../shared/models)
#   --dry-run       print the actions, change nothing
#
# Installs: binaries to /usr/local/bin, ONNX Runtime to /usr/local/lib/farsight,
# models to /usr/local/share/farsight/models, units to /etc/systemd/system,
# tmpfiles.d entry, stage configs to /etc/farsight (an existing config is kept:
# the new one goes beside it as .new), the service user `farsight`.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
prefix="" bin_dir="" ort_lib="${ORT_DYLIB_PATH:-}" models="$repo/../shared/models" dry=0
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix="$2"; shift 2 ;;
    --bin-dir) bin_dir="$2"; shift 2 ;;
    --ort-lib) ort_lib="$2"; shift 2 ;;
    --models) models="$2"; shift 2 ;;
    --dry-run) dry=1; shift ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) echo "install.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
stages="camera-ingest inference bin-projection costmap-fusion subgoal-selection velocity-servoing command-mux bridge"
say() { echo "install: $*"; }
act() { say "$*"; [ "$dry" = 1 ] || "$@"; }
if [ -z "$prefix" ] && [ "$dry" = 0 ] && [ "$(id -u)" != 0 ]; then
  echo "install.sh: run as root, or stage with --prefix DIR" >&2; exit 1
fi

if [ -z "$bin_dir" ]; then
  act cargo build --release --manifest-path "$repo/Cargo.toml" --workspace
  bin_dir="$repo/target/release"
fi
for s in $stages; do
  [ -x "$bin_dir/farsight-$s" ] || { echo "install.sh: $bin_dir/farsight-$s missing (build first or pass --bin-dir)" >&2; exit 1; }
done

act install -d "$prefix/usr/local/bin" "$prefix/usr/local/lib/farsight" \
  "$prefix/usr/local/share/farsight/models" "$prefix/usr/local/share/doc/farsight" \
  "$prefix/etc/farsight/models" "$prefix/etc/systemd/system" "$prefix/usr/lib/tmpfiles.d"
for s in $stages; do act install -m 0755 "$bin_dir/farsight-$s" "$prefix/usr/local/bin/"; done
act install -m 0755 "$bin_dir/farsight" "$prefix/usr/local/bin/"

if [ -z "$ort_lib" ]; then
  ort_lib="$(ls "${FARSIGHT_CACHE:-$HOME/.cache/farsight}"/onnxruntime-*/libonnxruntime.so.* 2>/dev/null | head -1 || true)"
fi
if [ -n "$ort_lib" ] && [ -f "$ort_lib" ]; then
  act install -m 0644 "$ort_lib" "$prefix/usr/local/lib/farsight/libonnxruntime.so"
else
  say "no ONNX Runtime library found: pass --ort-lib (inference needs it)"
fi
if [ -d "$models" ]; then
  act cp -r "$models/." "$prefix/usr/local/share/farsight/models/"
else
  say "no models folder at $models: put the ONNX files under /usr/local/share/farsight/models"
fi

# The simulator models trained in this repository travel with their configs.
for d in "$repo"/deploy/models/*/; do
  act cp -r "${d%/}" "$prefix/usr/local/share/farsight/models/"
done

# Model configs: their relative model paths point at the installed models.
for f in "$repo"/deploy/models/*.toml; do
  dest="$prefix/etc/farsight/models/$(basename "$f")"
  say "install $f -> $dest (model paths -> /usr/local/share/farsight/models)"
  [ "$dry" = 1 ] || sed 's|"\(\.\./\)*shared/models/|"/usr/local/share/farsight/models/|' "$f" > "$dest"
done
for s in $stages; do
  dest="$prefix/etc/farsight/$s.toml"
  if [ -e "$dest" ]; then
    act install -m 0644 "$repo/deploy/config/$s.toml" "$dest.new"
    say "kept your $dest; the shipped defaults are in $dest.new"
  else
    act install -m 0644 "$repo/deploy/config/$s.toml" "$dest"
  fi
done
act install -d "$prefix/etc/farsight/zenoh"
for f in robot.json5 users.txt; do
  dest="$prefix/etc/farsight/zenoh/$f"
  if [ -e "$dest" ]; then
    say "kept your $dest"
  else
    act install -m 0640 "$repo/deploy/zenoh/$f" "$dest"
  fi
done
say "change the passwords in $prefix/etc/farsight/zenoh/users.txt and robot.json5 before the robot leaves the lab"
for u in "$repo"/deploy/systemd/*; do act install -m 0644 "$u" "$prefix/etc/systemd/system/"; done
act install -m 0644 "$repo/deploy/tmpfiles.d/farsight.conf" "$prefix/usr/lib/tmpfiles.d/farsight.conf"
act install -m 0644 "$repo/README.md" "$prefix/usr/local/share/doc/farsight/README.md"

if [ -n "$prefix" ]; then
  say "staged under $prefix (no user created, systemd not touched)"
  exit 0
fi
if ! id farsight >/dev/null 2>&1; then
  act useradd --system --home-dir /var/lib/farsight --shell /usr/sbin/nologin --user-group farsight
fi
act systemd-tmpfiles --create /usr/lib/tmpfiles.d/farsight.conf
act systemctl daemon-reload
act systemctl enable farsight.target
say "done: systemctl start farsight.target; journalctl -u 'farsight-*' -f"
