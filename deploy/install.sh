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
# the new one goes beside it as .new), the service user `farsight`, and the
# zenoh router config /etc/farsight/zenoh/robot.json5, generated from the
# installed bridge.toml (its ACL follows the bridge's imports). The secrets in
# /etc/farsight/zenoh are root:farsight 0640: the units run as farsight. When
# staging as root, they get group farsight if that group exists here.
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
    -h|--help) sed -n '2,24p' "$0"; exit 0 ;;
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

# The service user first: the secrets below are installed with its group.
if [ -z "$prefix" ] && ! id farsight >/dev/null 2>&1; then
  act useradd --system --home-dir /var/lib/farsight --shell /usr/sbin/nologin --user-group farsight
fi
# Owner and group of the files the units must read but others must not.
secret_owner=()
if [ "$(id -u)" = 0 ] && { [ -z "$prefix" ] || getent group farsight >/dev/null; }; then
  secret_owner=(-o root -g farsight)
else
  say "no group farsight here (or not root): the files in $prefix/etc/farsight/zenoh stay $(id -un)-only; on the robot: chgrp farsight them"
fi

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
act install -d -m 0750 "${secret_owner[@]}" "$prefix/etc/farsight/zenoh"
# The router config (with the robot's ACL) comes from the bridge config that
# is now installed: the user's if kept, else the shipped one.
bridge_toml="$prefix/etc/farsight/bridge.toml"
[ -e "$bridge_toml" ] || bridge_toml="$repo/deploy/config/bridge.toml"
router="$(mktemp)"
trap 'rm -f "$router"' EXIT
say "generate robot.json5: $bin_dir/farsight-bridge --config $bridge_toml --print-router-config"
"$bin_dir/farsight-bridge" --config "$bridge_toml" --print-router-config > "$router"
for f in robot.json5 users.txt; do
  dest="$prefix/etc/farsight/zenoh/$f"
  src="$repo/deploy/zenoh/$f"
  [ "$f" = robot.json5 ] && src="$router"
  if [ -e "$dest" ] && cmp -s "$src" "$dest"; then
    say "$dest is up to date"
  elif [ -e "$dest" ]; then
    act install -m 0640 "${secret_owner[@]}" "$src" "$dest.new"
    say "kept your $dest; the generated one is in $dest.new (its ACL follows bridge.toml's imports; the bridge warns while they differ)"
  else
    act install -m 0640 "${secret_owner[@]}" "$src" "$dest"
  fi
  # A file kept from an older install may be root:root, which the units cannot read.
  if [ -e "$dest" ] && [ ${#secret_owner[@]} -gt 0 ] \
     && [ "$(stat -c %U:%G:%a "$dest")" != root:farsight:640 ]; then
    act chown root:farsight "$dest"
    act chmod 0640 "$dest"
  fi
done
say "change the passwords in $prefix/etc/farsight/zenoh/users.txt and robot.json5 before the robot leaves the lab"
for u in "$repo"/deploy/systemd/*; do act install -m 0644 "$u" "$prefix/etc/systemd/system/"; done
act install -m 0644 "$repo/deploy/tmpfiles.d/farsight.conf" "$prefix/usr/lib/tmpfiles.d/farsight.conf"
act install -m 0644 "$repo/README.md" "$prefix/usr/local/share/doc/farsight/README.md"
act install -m 0644 "$repo/NOTICE" "$prefix/usr/local/share/doc/farsight/NOTICE"

if [ -n "$prefix" ]; then
  say "staged under $prefix (no user created, systemd not touched)"
  exit 0
fi
act systemd-tmpfiles --create /usr/lib/tmpfiles.d/farsight.conf
act systemctl daemon-reload
act systemctl enable farsight.target
say "done: systemctl start farsight.target; journalctl -u 'farsight-*' -f"
