#!/bin/sh
# bogiemon's offline installer, run from an unpacked bundle (docs/gateway.md): needs python3 (3.11,
# 3.12 or 3.13, its venv module; no pip, no network) and the bundle's folder.
#
#   sudo ./install.sh              install this bundle's version (or upgrade to it) and switch to it
#   sudo ./install.sh --enable     the same, then enable and start bogiemon.service
#   sudo /opt/bogiemon/install.sh --rollback    back to the version installed before (no bundle needed)
#   /opt/bogiemon/install.sh --status           the versions installed, and which runs
#
# Layout: each version is a venv of its own, /opt/bogiemon/versions/<version>; /opt/bogiemon/current
# and /opt/bogiemon/previous are symlinks to two of them, /opt/bogiemon/bin is current/bin (the
# units run /opt/bogiemon/bin/bogiemon). A switch is a rename of a symlink: atomic, and the old tree
# is kept for a rollback (older ones are removed). The new version checks the config in force
# (/etc/bogiemon/bogiemon.toml) before it is switched to: a config it refuses leaves the running one.
# /etc/bogiemon is never overwritten (the shipped default goes beside it as bogiemon.toml.dist) and
# /var/lib/bogiemon (the event store; systemd's StateDirectory) is never touched.
set -eu

PREFIX=${BOGIEMON_PREFIX:-/opt/bogiemon}
ETC=${BOGIEMON_ETC:-/etc/bogiemon}
UNIT_DIR=${BOGIEMON_UNIT_DIR:-/etc/systemd/system}
NETWORK_DIR=${BOGIEMON_NETWORK_DIR:-/etc/systemd/network}
UNITS="bogiemon.service bogiemon-mqtt.service"
HERE=$(cd "$(dirname "$0")" && pwd)

say() { echo "install.sh: $*"; }
fail() { echo "install.sh: error: $*" >&2; exit 2; }

# ln -s then rename over the old link: a reader sees the old target or the new one, never none.
switch_link() {  # switch_link TARGET LINK
    ln -sfn "$1" "$2.new"
    mv -T "$2.new" "$2"
}

version_of() {  # the version a link points to, or nothing
    if [ -L "$1" ]; then basename "$(readlink "$1")"; fi
}

systemd_running() { [ -d /run/systemd/system ] && command -v systemctl >/dev/null 2>&1; }

# The units of the version now current, and a restart of whichever of them runs.
apply_units() {
    mkdir -p "$UNIT_DIR"
    for unit in $UNITS; do
        install -m 0644 "$PREFIX/current/share/bogiemon/systemd/$unit" "$UNIT_DIR/$unit"
    done
    if systemd_running; then
        systemctl daemon-reload
        for unit in $UNITS; do
            if systemctl is-active --quiet "$unit"; then
                say "restarting $unit"
                systemctl restart "$unit"
            fi
        done
    fi
}

status() {
    say "current: $(version_of "$PREFIX/current") ($PREFIX/current)"
    say "previous: $(version_of "$PREFIX/previous")"
    if [ -d "$PREFIX/versions" ]; then
        say "installed:$(for tree in "$PREFIX"/versions/*; do printf ' %s' "$(basename "$tree")"; done)"
    fi
}

rollback() {
    [ -L "$PREFIX/previous" ] || fail "no previous version under $PREFIX to roll back to"
    old=$(version_of "$PREFIX/current")
    back=$(version_of "$PREFIX/previous")
    [ -f "$PREFIX/versions/$back/.bogiemon-complete" ] || fail "$PREFIX/versions/$back is not a complete install"
    switch_link "versions/$back" "$PREFIX/current"
    switch_link "versions/$old" "$PREFIX/previous"
    apply_units
    say "rolled back from $old to $back (roll forward again with --rollback)"
}

install_bundle() {
    if [ ! -f "$HERE/VERSION" ] || [ ! -d "$HERE/wheels" ]; then
        fail "$HERE is not an unpacked bundle (no VERSION or wheels/): run the install.sh of a bundle"
    fi
    version=$(cat "$HERE/VERSION")
    arch=$(cat "$HERE/ARCH")
    machine=$(uname -m)
    [ "$machine" = "$arch" ] || fail "this bundle is for $arch, this machine is $machine: use bogiemon-$version-$machine.tar.gz"
    command -v python3 >/dev/null 2>&1 || fail "python3 is not installed (3.11, 3.12 or 3.13; Debian: apt install python3)"
    abi=$(python3 -c 'import sys; print("cp%d%d" % sys.version_info[:2])')
    lock="$HERE/lock/$arch-$abi.txt"
    [ -f "$lock" ] || fail "python3 is $(python3 -V 2>&1 | cut -d' ' -f2); this bundle holds wheels for CPython 3.11, 3.12 and 3.13"
    python3 -c 'import venv' 2>/dev/null || fail "python3 has no venv module (Debian: apt install libpython3-stdlib)"
    if [ -e "$PREFIX" ] && [ ! -d "$PREFIX/versions" ] && [ -f "$PREFIX/pyvenv.cfg" ]; then
        fail "$PREFIX is a venv installed by pip (docs/gateway.md, the PyPI way): move it aside (mv $PREFIX $PREFIX.pip) and run again"
    fi
    if (cd "$HERE" && sha256sum --quiet -c SHA256SUMS) >/dev/null 2>&1; then :; else
        fail "the bundle's files do not match its SHA256SUMS: copy it again"
    fi

    target="$PREFIX/versions/$version"
    if [ -f "$target/.bogiemon-complete" ]; then
        say "bogiemon $version is installed already ($target)"
    else
        say "installing bogiemon $version into $target (CPython $abi, $arch)"
        rm -rf "$target"  # an install cut short before: its venv is not trusted
        mkdir -p "$PREFIX/versions"
        python3 -m venv --without-pip "$target"
        for pip_wheel in "$HERE"/wheels/pip-*.whl; do :; done
        # The lock without pip: pip is the installer's, run from its wheel, not the gateway's.
        requirements=$(mktemp)
        grep -v '^pip==' "$lock" > "$requirements"
        # pip from its wheel, run by the new venv's python: it installs there, from the bundle only
        # (--isolated: no pip.conf nor PIP_* variable of this machine adds an index or a link),
        # each wheel checked against the lock's hash, nothing resolved.
        if ! "$target/bin/python" "$pip_wheel/pip" install --isolated --quiet --disable-pip-version-check --no-index --no-deps \
            --no-warn-script-location --find-links "$HERE/wheels" --require-hashes -r "$requirements" -r "$HERE/lock/bogiemon.txt"; then
            rm -f "$requirements"
            fail "pip could not install the bundle's wheels into $target (above)"
        fi
        rm -f "$requirements"
        mkdir -p "$target/share/bogiemon"
        cp -R "$HERE/systemd" "$target/share/bogiemon/systemd"
        cp "$HERE/config/bogiemon.toml" "$target/share/bogiemon/bogiemon.toml.dist"
        cp "$HERE/install.sh" "$target/share/bogiemon/install.sh"
        "$target/bin/bogiemon" --version >/dev/null || fail "the new install does not start: $target/bin/bogiemon --version failed"
        touch "$target/.bogiemon-complete"
    fi

    mkdir -p "$ETC"
    cp "$target/share/bogiemon/bogiemon.toml.dist" "$ETC/bogiemon.toml.dist"
    if [ ! -e "$ETC/bogiemon.toml" ]; then
        cp "$target/share/bogiemon/bogiemon.toml.dist" "$ETC/bogiemon.toml"
        say "wrote the default config $ETC/bogiemon.toml: edit [source] and [state] for this wagon"
    fi
    if ! "$target/bin/bogiemon" check-config "$ETC/bogiemon.toml" >/dev/null; then
        fail "bogiemon $version refuses $ETC/bogiemon.toml (above); the running version is unchanged. Fix the config and run install.sh again"
    fi

    current=$(version_of "$PREFIX/current")
    if [ "$current" != "$version" ]; then
        [ -n "$current" ] && switch_link "versions/$current" "$PREFIX/previous"
        switch_link "versions/$version" "$PREFIX/current"
    fi
    switch_link "current/bin" "$PREFIX/bin"
    cp "$target/share/bogiemon/install.sh" "$PREFIX/install.sh.new" && mv "$PREFIX/install.sh.new" "$PREFIX/install.sh"
    if [ -d "$HERE/systemd" ] && [ ! -e "$NETWORK_DIR/80-can0.network" ]; then
        mkdir -p "$NETWORK_DIR"
        install -m 0644 "$HERE/systemd/80-can0.network" "$NETWORK_DIR/80-can0.network"
        say "wrote $NETWORK_DIR/80-can0.network (can0 at 500 kbit/s, systemd-networkd)"
    fi
    apply_units

    # Two versions are kept: the current and the previous one (a rollback's); older trees go.
    keep_previous=$(version_of "$PREFIX/previous")
    for tree in "$PREFIX"/versions/*; do
        name=$(basename "$tree")
        if [ "$name" != "$version" ] && [ "$name" != "$keep_previous" ]; then
            say "removing bogiemon $name (older than the previous version)"
            rm -rf "$tree"
        fi
    done
    if [ -n "$current" ] && [ "$current" != "$version" ]; then
        say "upgraded bogiemon $current -> $version (undo with: $PREFIX/install.sh --rollback)"
    else
        say "bogiemon $version is current"
    fi
}

case "${1:-}" in
    "") install_bundle ;;
    --enable)
        install_bundle
        systemd_running || fail "systemd is not running here: start the service with your init system"
        systemctl enable --now bogiemon.service
        ;;
    --rollback) rollback ;;
    --status) status ;;
    -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//' ;;
    *) fail "unknown option '$1' (--enable, --rollback, --status, --help)" ;;
esac
