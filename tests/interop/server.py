"""A pymodbus TCP server (an implementation nobody here wrote) serving the documented register
map of io-map/trijoint.json: 18 coils, 18 discrete inputs, 2 input registers, 3 holding
registers. The soft-PLC runs against it; this script reports what the soft-PLC wrote.

Usage: server.py PORT SECONDS. Prints "ready" once it accepts connections, then, once the soft-PLC has written the PWM
period (holding register 0 = 50) and set the clear-error coils (14, 15), "period 50" and exits 0;
exits 1 if that does not happen within SECONDS."""
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
threading.Thread(target=lambda: StartTcpServer(context=context, address=("127.0.0.1", port)), daemon=True).start()
# "ready" once the server accepts connections (its thread binds the port after a while: the
# test waited a fixed half second before, which a busy machine can outlast).
started = time.time()
while True:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        break
    except OSError:
        if time.time() - started > 30:
            print("FAILED: the server did not listen within 30 s", flush=True)
            sys.exit(1)
        time.sleep(0.02)
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
