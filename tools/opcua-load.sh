#!/usr/bin/env bash
# The OPC UA server's cost (docs/performance.md, "OPC UA"): runs the TRIJOINT in real time for 50 s
# with OPC UA off, idle, and with CLIENTS asyncua clients subscribed to every variable and to the
# machine's condition events, while a user presses Stop and acknowledges every 5 s (so events
# flow), and prints the fast class's lateness and execution time, the resident memory, the
# process's CPU time and what the clients received.
#
#   cargo build --release; cargo test --test realtime opcua   # makes target/tmp/interop-venv
#   tools/opcua-load.sh NAME CLIENTS on|off          # e.g. off1 0 off; zero1 0 on; eight1 8 on
set -euo pipefail
cd "$(dirname "$0")/.."
name=$1 clients=$2 opc=$3
out=target/opcua-load
mkdir -p "$out"
python=target/tmp/interop-venv/bin/python
url=opc.tcp://127.0.0.1:4860
printf '{"users": [{"name": "operator", "password": "a-long-passphrase"}]}' >"$out/users.json"
chmod 600 "$out/users.json"
# Sessions for the clients and the one pressing Stop (all from 127.0.0.1, which may hold half of
# the connections: 20 sessions, 24 connections, 12 from one source).
if [ "$opc" = on ]; then
    server=(--opcua "$url" --opcua-users "$out/users.json" --opcua-max-sessions 20)
else
    server=(--opcua none)
fi
XDG_DATA_HOME="$out/xdg" target/release/pkm-plc run --duration 50 --hmi none "${server[@]}" \
    --summary "$out/$name.json" >"$out/$name.log" 2>&1 &
pid=$!
sleep 2
for i in $(seq 1 "$clients"); do
    # 35 s: eight Python clients starting at once take seconds of CPU to connect.
    "$python" tests/interop/opcua_client.py subscribe "$url/" trijoint 35 all events >"$out/$name-c$i.json" 2>/dev/null &
done
if [ "$opc" = on ] && [ "$clients" -gt 0 ]; then
    # Events: Stop and its acknowledgement every 5 s (the Stop condition raised, acknowledged, cleared).
    (sleep 8; for _ in 1 2 3 4 5 6; do
        sleep 5
        "$python" tests/interop/opcua_client.py call "$url/" trijoint --user operator --password a-long-passphrase \
            Stop wait=ERROR Acknowledge >/dev/null 2>&1 || true
    done) &
fi
sleep 18
rss=$(ps -o rss= -p "$pid")
t1=$(awk '{print $14+$15}' "/proc/$pid/stat")
sleep 10
t2=$(awk '{print $14+$15}' "/proc/$pid/stat")
wait
python3 - "$out" "$name" "$rss" "$t1" "$t2" <<'PY'
import glob, json, sys
out, name, rss, t1, t2 = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
s = json.load(open(f"{out}/{name}.json"))
f = [c for c in s["task_classes"] if c["name"] == "fast"][0]
L, E = f["lateness_us"], f["exec_us"]
clients = [json.load(open(p)) for p in sorted(glob.glob(f"{out}/{name}-c*.json"))]
cycles = [c["counts"].get("trijoint.TaskClasses.main.Cycles") for c in clients]
events = [c.get("events") for c in clients]
latency = [(round(c["latency_ms"]["p50"], 1), round(c["latency_ms"]["p99"], 1)) for c in clients]
print(f"{name}: fast lateness p50/p99/max {L['p50']:.1f}/{L['p99']:.1f}/{L['max']:.1f} us, "
      f"exec mean/p99/max {E['mean']:.1f}/{E['p99']:.1f}/{E['max']:.1f} us, overruns {f['overruns']}; "
      f"RSS {rss} kB; CPU {(t2 - t1) / 10:.1f} % of a core over 10 s; "
      f"cycle-count updates per client {cycles}; events per client {events}; latency p50/p99 ms {latency}")
PY
