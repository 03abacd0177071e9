#!/bin/sh
# Inside the Debian root of tests/bundle/in_debian_root.sh, offline: install the bundle, check the
# config, replay a simulated broken spring, run the daemon on it, upgrade and roll back.
#   sh inside.sh BUNDLE.tar.gz FAULT.csv   (from /tmp/bogiemon-test, which holds both)
set -eu
BUNDLE=$1 FAULT=$2
cd /tmp/bogiemon-test
now() { cut -d' ' -f1 /proc/uptime; }
step() { echo "inside: $1 ($(awk "BEGIN{printf \"%.1f\", $(now) - $T}") s)"; T=$(now); }
fail() { echo "inside: FAIL: $*" >&2; exit 1; }
T=$(now)

python3 - <<'PY' || fail "the network is reachable: the test must run offline"
import socket
for host, port in (("deb.debian.org", 80), ("pypi.org", 443), ("151.101.0.223", 443)):
    try:
        socket.create_connection((host, port), timeout=5).close()
    except OSError:
        continue
    raise SystemExit(f"reached {host}:{port}")
PY
echo "inside: $(uname -m), $(python3 -V), no network"

tar xzf "$BUNDLE"
BUNDLE_DIR=$(basename "$BUNDLE" .tar.gz)
"./$BUNDLE_DIR/install.sh"
step "installed"
/opt/bogiemon/bin/bogiemon --version
du -sm /opt/bogiemon/versions/* | sed 's/^/inside: on disk, MB: /'

# The wagon's config: the demo wagon's commissioning, loaded.
cp demo_calibration.toml /etc/bogiemon/
cat > /etc/bogiemon/bogiemon.toml <<TOML
include = ["demo_calibration.toml"]
[decision]
load = "full"
TOML
cp /etc/bogiemon/bogiemon.toml keeper.toml
/opt/bogiemon/bin/bogiemon check-config /etc/bogiemon/bogiemon.toml > check.txt || fail "check-config refused the config: $(cat check.txt)"
step "check-config"

/opt/bogiemon/bin/bogiemon replay "$FAULT" --config /etc/bogiemon/bogiemon.toml > replay.txt 2>&1 || { cat replay.txt; fail "replay failed"; }
grep -q CONFIRMED replay.txt || { cat replay.txt; fail "replay confirmed nothing"; }
sed 's/^/inside: replay: /' replay.txt
step "replay"

# `bogiemon run` on a replay source: the daemon itself, its SQLite store in /var/lib/bogiemon.
cat > /etc/bogiemon/run.toml <<TOML
include = ["demo_calibration.toml"]
[decision]
load = "full"
[source]
kind = "replay"
path = "/tmp/bogiemon-test/$FAULT"
# As fast as the daemon reads it, not at the pace of the wagon.
realtime = false
TOML
/opt/bogiemon/bin/bogiemon run --config /etc/bogiemon/run.toml > run.log 2>&1 || { tail -20 run.log; fail "run failed"; }
/opt/bogiemon/bin/bogiemon events --config /etc/bogiemon/run.toml > events.txt
grep -q CONFIRMED events.txt || { cat events.txt; tail -20 run.log; fail "run stored no CONFIRMED"; }
python3 -c "
import sqlite3
rows = sqlite3.connect('file:/var/lib/bogiemon/events.sqlite3?mode=ro', uri=True).execute('select count(*) from events').fetchone()
print('inside: /var/lib/bogiemon/events.sqlite3 holds', rows[0], 'events')
"
sed 's/^/inside: events: /' events.txt
step "run"

# An upgrade to another version (this bundle as 'VERSION+upgrade') keeps the config and the store,
# and a rollback comes back.
cp -R "$BUNDLE_DIR" upgrade
echo "$(cat "$BUNDLE_DIR/VERSION")+upgrade" > upgrade/VERSION
(cd upgrade && sed 's/^[0-9a-f]*  //' SHA256SUMS | xargs sha256sum > SHA256SUMS.new && mv SHA256SUMS.new SHA256SUMS)
./upgrade/install.sh
[ "$(basename "$(readlink /opt/bogiemon/current)")" = "$(cat upgrade/VERSION)" ] || fail "the upgrade is not current"
cmp -s keeper.toml /etc/bogiemon/bogiemon.toml || fail "the upgrade changed /etc/bogiemon/bogiemon.toml"
/opt/bogiemon/bin/bogiemon events --config /etc/bogiemon/run.toml | grep -q CONFIRMED || fail "the store lost its events in the upgrade"
/opt/bogiemon/install.sh --rollback
[ "$(basename "$(readlink /opt/bogiemon/current)")" = "$(cat "$BUNDLE_DIR/VERSION")" ] || fail "the rollback did not come back"
/opt/bogiemon/bin/bogiemon events --config /etc/bogiemon/run.toml | grep -q CONFIRMED || fail "the store lost its events in the rollback"
/opt/bogiemon/install.sh --status
step "upgrade and rollback"
echo "inside: PASS"
