#!/usr/bin/env bash
# Checks a built Debian package (CI runs it on what `cargo deb` made): the files where the unit
# and the documentation say they are, the configuration marked as conffiles, and the installed
# configuration valid as the service runs it (its I/O maps found relative to /etc/pkm-plc, every
# machine's too).
set -euo pipefail
deb="$1"
root="$(mktemp -d)"
trap 'rm -rf "$root"' EXIT
dpkg-deb -x "$deb" "$root"
dpkg-deb -e "$deb" "$root/DEBIAN"
fail() { echo "check-deb: $*" >&2; exit 1; }
for f in usr/bin/pkm-plc usr/lib/systemd/system/pkm-plc.service etc/default/pkm-plc \
         etc/pkm-plc/config.json etc/pkm-plc/io-map/trijoint.json usr/share/pkm-plc/programs \
         usr/share/doc/pkm-plc/docs/hardware.md; do
    [ -e "$root/$f" ] || fail "$f is missing"
done
grep -qx "/etc/pkm-plc/config.json" "$root/DEBIAN/conffiles" || fail "config.json is not a conffile"
unit="$root/usr/lib/systemd/system/pkm-plc.service"
for key in Type=notify WatchdogSec= Restart=on-failure LimitRTPRIO= LimitMEMLOCK= \
           "ExecStart=/usr/bin/pkm-plc run --config /etc/pkm-plc/config.json"; do
    grep -q "^$key" "$unit" || fail "the unit has no $key"
done
# The configuration as installed: the service's, and every machine's beside it.
bin="$root/usr/bin/pkm-plc"
"$bin" check --config "$root/etc/pkm-plc/config.json" >/dev/null || fail "the installed config.json is refused"
for machine in "$root"/etc/pkm-plc/machines/*.json; do
    "$bin" check --config "$machine" >/dev/null || fail "the installed $(basename "$machine") is refused"
done
echo "check-deb: $(basename "$deb") holds the binary, the unit, the configuration (valid as installed) and the docs"
