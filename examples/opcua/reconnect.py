"""Watching a pkm-plc over OPC UA with Python's asyncua, through server restarts.

asyncua's client does not reconnect by itself: once the server has gone (a restart, a service
update, a power cut of the PLC computer) its subscription stays silent. This recipe connects,
subscribes to the machine's State, checks the connection every second, and when it is lost
connects and subscribes again after a pause — so a dashboard goes on by itself once the PLC is
back. Usage (pip install asyncua):

    python3 reconnect.py opc.tcp://127.0.0.1:4840/ trijoint [SECONDS]

It prints a line per State change (`ox-x: READY`) and one per lost connection; with SECONDS it
ends after that long and prints, as its last line, JSON with the states seen and the reconnects.
"""

import asyncio
import json
import sys
import time

from asyncua import Client, ua

NS = "urn:pkm-plc"
PAUSE_S = 2.0


class States:
    """Keeps the State values the subscription delivers."""

    def __init__(self, machine):
        self.machine = machine
        self.seen = []

    def datachange_notification(self, node, value, data):
        self.seen.append(value)
        print(f"{self.machine}: {value}", flush=True)


async def watch_once(url, machine, states, until):
    """One connection: subscribes to the State and watches it until the connection is lost
    (raises) or `until` (a monotonic time) passes."""
    client = Client(url, timeout=5)
    await client.connect()
    try:
        ns = await client.get_namespace_index(NS)
        state = await client.nodes.objects.get_child([f"{ns}:PkmPlc", f"{ns}:{machine}", f"{ns}:State"])
        subscription = await client.create_subscription(500, states)
        await subscription.subscribe_data_change(state)
        while time.monotonic() < until:
            await asyncio.sleep(1)
            # Raises once the server has gone (its shutdown notice, a closed connection).
            await client.check_connection()
    finally:
        try:
            await client.disconnect()
        except Exception:
            pass


async def watch(url, machine, seconds=None):
    states = States(machine)
    until = time.monotonic() + seconds if seconds else float("inf")
    reconnects, seen_before = 0, 0
    while time.monotonic() < until:
        try:
            await watch_once(url, machine, states, until)
        except (OSError, asyncio.TimeoutError, ConnectionError, ua.UaError) as e:
            reconnects += 1
            seen_before = len(states.seen)
            print(f"connection lost ({type(e).__name__}); connecting again in {PAUSE_S} s", flush=True)
            await asyncio.sleep(PAUSE_S)
    # The states seen, the reconnects, and how many states came after the last one.
    print(json.dumps({"states": states.seen, "reconnects": reconnects, "after_reconnect": len(states.seen) - seen_before}))


if __name__ == "__main__":
    asyncio.run(watch(sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) > 3 else None))
