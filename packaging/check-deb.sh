#!/usr/bin/env bash
# Checks a built Debian package (CI runs it on what `cargo deb` made): the files where the unit
# and the documentation say they are, the unit as systemd reads it, the maintainer scripts, the
# configuration marked as conffiles, and the installed configuration valid as the service runs it
# (its I/O maps found relative to /etc/pkm-plc, every machine's too).
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
# The unit as this systemd reads it (Debian 12: systemd 252): `systemd-analyze verify` names an
# unknown key or a key in the wrong section, but exits 0 for it, so any line it prints fails here.
# It also wants ExecStart's binary to exist: a copy of the unit runs the package's own.
command -v systemd-analyze >/dev/null 2>&1 || fail "systemd-analyze is missing (Debian: apt install systemd)"
verify_dir="$root/verify"
mkdir -p "$verify_dir"
sed "s|^ExecStart=/usr/bin/pkm-plc |ExecStart=$root/usr/bin/pkm-plc |" "$unit" >"$verify_dir/pkm-plc.service"
verified="$(systemd-analyze verify "$verify_dir/pkm-plc.service" 2>&1)" \
    || fail "systemd-analyze verify refuses the unit: $verified"
[ -z "$verified" ] || fail "systemd-analyze verify ($(systemd-analyze --version | head -n 1)) says: $verified"
for key in RestartPreventExitStatus=2 StartLimitBurst=; do
    grep -q "^$key" "$unit" || fail "the unit has no $key"
done
# The maintainer scripts: systemd told of the unit on install and removal, a running service
# restarted after an upgrade, stopped on removal.
grep -q "daemon-reload" "$root/DEBIAN/postinst" || fail "postinst does not reload systemd"
grep -q "try-restart pkm-plc.service" "$root/DEBIAN/postinst" || fail "postinst does not restart the service after an upgrade"
grep -q "stop pkm-plc.service" "$root/DEBIAN/prerm" || fail "prerm does not stop the service on removal"
grep -q "daemon-reload" "$root/DEBIAN/postrm" || fail "postrm does not reload systemd"
# The configuration as installed: the service's, and every machine's beside it.
bin="$root/usr/bin/pkm-plc"
"$bin" check --config "$root/etc/pkm-plc/config.json" >/dev/null || fail "the installed config.json is refused"
for machine in "$root"/etc/pkm-plc/machines/*.json; do
    "$bin" check --config "$machine" >/dev/null || fail "the installed $(basename "$machine") is refused"
done
echo "check-deb: $(basename "$deb") holds the binary, the unit (verified by $(systemd-analyze --version | head -n 1)), its maintainer scripts, the configuration (valid as installed) and the docs"
