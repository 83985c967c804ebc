#!/usr/bin/env bash
# Install (or update) the odfc-rig depth service on a robot computer. Idempotent: run it again
# after a `git pull` to update; existing /etc/rig files are kept.
#
#   sudo deploy/install.sh               install from this checkout
#   DRY_RUN=1 deploy/install.sh          print what would be done, change nothing
#   PREFIX=/tmp/root deploy/install.sh   install into a staging tree (no user, no systemctl/udevadm)
#
# Environment: PYTHON (default python3), SKIP_PIP=1 (create the venv but do not pip install).
set -euo pipefail

SRC="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PREFIX="${PREFIX:-}"
DRY_RUN="${DRY_RUN:-0}"
PYTHON="${PYTHON:-python3}"
SKIP_PIP="${SKIP_PIP:-0}"
RIG_USER="rig"

OPT="$PREFIX/opt/rig"
ETC="$PREFIX/etc/rig"
UNIT_DIR="$PREFIX/etc/systemd/system"
UDEV_DIR="$PREFIX/etc/udev/rules.d"
STATE="$PREFIX/var/lib/rig"
CACHE="$PREFIX/var/cache/rig"

say() { printf '%s\n' "$*"; }
run() {
    if [ "$DRY_RUN" = 1 ]; then
        say "would run: $*"
    else
        "$@"
    fi
}
system_wide() { [ -z "$PREFIX" ]; }

# install_file SRC DEST MODE [keep]: copy if missing or different; "keep" never overwrites.
install_file() {
    local src="$1" dest="$2" mode="$3" keep="${4:-}"
    if [ -e "$dest" ]; then
        if [ -n "$keep" ]; then
            say "kept      $dest (local file; compare with $src)"
            return
        fi
        if cmp -s "$src" "$dest"; then
            say "unchanged $dest"
            return
        fi
    fi
    run install -D -m "$mode" "$src" "$dest"
    say "installed $dest"
}

if system_wide && [ "$DRY_RUN" != 1 ] && [ "$(id -u)" -ne 0 ]; then
    say "error: run as root (sudo), or set PREFIX=DIR to stage, or DRY_RUN=1" >&2
    exit 2
fi

# 1. service user in the camera groups
if system_wide; then
    for group in video plugdev; do
        getent group "$group" >/dev/null || run groupadd --system "$group"
    done
    if getent passwd "$RIG_USER" >/dev/null; then
        say "unchanged user $RIG_USER"
    else
        run useradd --system --home-dir /var/lib/rig --no-create-home --shell /usr/sbin/nologin "$RIG_USER"
        say "created   user $RIG_USER"
    fi
    run usermod -a -G video,plugdev "$RIG_USER"
fi

# 2. virtual environment and the package
if [ -x "$OPT/venv/bin/python" ]; then
    say "unchanged venv $OPT/venv"
else
    run mkdir -p "$OPT"
    run "$PYTHON" -m venv "$OPT/venv"
    say "created   venv $OPT/venv"
fi
if [ "$SKIP_PIP" = 1 ]; then
    say "skipped   pip install (SKIP_PIP=1)"
else
    run "$OPT/venv/bin/pip" install --quiet --upgrade pip
    run "$OPT/venv/bin/pip" install --quiet --upgrade "$SRC"
    say "installed odfc-rig into $OPT/venv"
fi
install_file "$SRC/README.md" "$OPT/README.md" 0644

# 3. configuration (never overwritten), unit, udev rule
install_file "$SRC/deploy/rig.example.yaml" "$ETC/rig.yaml" 0640 keep
install_file "$SRC/deploy/rig.env.example" "$ETC/rig.env" 0640 keep
install_file "$SRC/deploy/rig.service" "$UNIT_DIR/rig.service" 0644
install_file "$SRC/deploy/99-rig-cameras.rules" "$UDEV_DIR/99-rig-cameras.rules" 0644
run mkdir -p "$STATE/recordings" "$CACHE"

# 4. ownership and reloads (system-wide only)
if system_wide; then
    run chown root:"$RIG_USER" "$ETC" "$ETC/rig.yaml" "$ETC/rig.env"
    run chmod 0750 "$ETC"
    run chown -R "$RIG_USER":"$RIG_USER" "$STATE" "$CACHE"
    if command -v udevadm >/dev/null 2>&1; then
        run udevadm control --reload
        run udevadm trigger --subsystem-match=video4linux --subsystem-match=usb
    fi
    if command -v systemctl >/dev/null 2>&1; then
        run systemctl daemon-reload
    fi
fi

say "done. Next: put the rig calibration at /etc/rig/calibration.yaml, edit /etc/rig/rig.yaml"
say "(camera ports in $UDEV_DIR/99-rig-cameras.rules), then: sudo systemctl enable --now rig"
