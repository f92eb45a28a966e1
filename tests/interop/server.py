"""A pymodbus TCP server (an implementation nobody here wrote) serving the documented register
map of io-map/trijoint.json: 18 coils, 18 discrete inputs, 2 input registers, 3 holding
registers. The soft-PLC runs against it; this script reports what the soft-PLC wrote.

Usage: server.py PORT SECONDS. Prints "ready" once this server accepts connections on PORT (its
own connection callback saw the probe: another process that took the port first would answer the
probe too), then, once the soft-PLC has written the PWM period (holding register 0 = 50) and set
the clear-error coils (14, 15), "period 50" and exits 0; exits 1 if that does not happen within
SECONDS, or if the server cannot listen on PORT, printing a line that starts with "FAILED: ".

It runs at SCHED_FIFO priority 70 where the process may, as `pkm-plc io-sim` answers its clients:
a station's own processor is never starved by the PC's other work. At normal priority it shares
the CPUs with every process of the real-time suite's tests running beside it, and a station that
answers later than the soft-PLC's request timeout (100 ms) is a bus fault, as it must be."""
import os
import socket
import sys
import threading
import time

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.server import StartTcpServer

port, seconds = int(sys.argv[1]), float(sys.argv[2])
store = ModbusSlaveContext(
    co=ModbusSequentialDataBlock(0, [False] * 20),
    di=ModbusSequentialDataBlock(0, [False] * 20),
    ir=ModbusSequentialDataBlock(0, [0] * 4),
    hr=ModbusSequentialDataBlock(0, [0] * 5),
)
context = ModbusServerContext(slaves=store, single=True)
# Before the server's thread starts: the threads it makes inherit the policy.
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(70))
except (PermissionError, OSError):
    pass
connected = threading.Event()
failure = []


def serve():
    try:
        StartTcpServer(
            context=context,
            address=("127.0.0.1", port),
            trace_connect=lambda up: up and connected.set(),
        )
    except Exception as e:  # the port taken, say: said by the main thread
        failure.append(e)


server = threading.Thread(target=serve, daemon=True)
server.start()
# "ready" once this server accepted the probe (its thread binds the port after a while: the test
# waited a fixed half second before, which a busy machine can outlast).
started = time.time()
while not connected.is_set():
    if failure or not server.is_alive():
        print(f"FAILED: the server cannot listen on port {port}: {failure[0] if failure else 'it ended'}", flush=True)
        sys.exit(1)
    if time.time() - started > 30:
        print(f"FAILED: the server did not accept a connection on port {port} within 30 s (taken by another process?)", flush=True)
        sys.exit(1)
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except OSError:
        pass
    connected.wait(0.05)
print("ready", flush=True)
seen_clear = False
deadline = time.time() + seconds
while time.time() < deadline:
    time.sleep(0.05)
    coils = store.getValues(1, 14, count=2)
    seen_clear = seen_clear or all(coils)
    if store.getValues(3, 0, count=1)[0] == 50 and seen_clear:
        print("period 50", flush=True)
        sys.exit(0)
print(f"FAILED: holding 0 = {store.getValues(3, 0, count=1)}, clear-error pulse seen: {seen_clear}", flush=True)
sys.exit(1)
