"""A pymodbus client (an implementation nobody here wrote) drives `pkm-plc io-sim` serving the
TRIJOINT's I/O map as an X20BC0087 bus controller. It is written from the bus controller's public
register description, not from pkm-plc's code: module table at 0xA000 (16 registers per module),
process data by byte index (digital bits at index*8 + bit, words at index/2, outputs from
0x0800), process counts at 0x1100, product data at 0x1080, node number at 0x1180, watchdog at
0x1040-0x1044 (threshold ms, elapsed, status, mode, reset), status and error bits at
0x1186-0x1187, X2X counters at 0x11C0.

Usage: bc_client.py HOST:PORT NODE. Prints "ok" and exits 0 when every check holds, else prints
the failing check and exits 1."""
import sys
import time

from pymodbus.client import ModbusTcpClient

WATCHDOG_EXPIRED = 1 << 5


def check(condition, what):
    if not condition:
        print(f"FAILED: {what}")
        sys.exit(1)


def holding(address, count):
    r = client.read_holding_registers(address, count=count)
    check(not r.isError(), f"read holding registers {address:#06x} ({count}): {r}")
    return r.registers


def write(address, value):
    r = client.write_register(address, value)
    check(not r.isError(), f"write holding register {address:#06x} = {value:#x}: {r}")


def coil(address):
    r = client.read_coils(address, count=1)
    check(not r.isError(), f"read coil {address}: {r}")
    return r.bits[0]


host, port = sys.argv[1].rsplit(":", 1)
node = int(sys.argv[2])
client = ModbusTcpClient(host, port=int(port))
check(client.connect(), "connect")

# Process counts: 5 modules; (count, bytes) of analog in, analog out, digital in, digital out.
counts = holding(0x1100, 9)
check(counts[0] == 5, f"number of modules: {counts}")
check(counts[1:] == [2, 4, 1, 6, 2, 3, 4, 5], f"process data counts and sizes: {counts}")

# The module table: five records, then an empty slot.
table = holding(0xA000, 16 * 6)
records = [table[16 * i:16 * (i + 1)] for i in range(6)]
check(all(r[0] != 0 for r in records[:5]) and records[5][0] == 0, f"five modules, then the end: {records}")
check([r[1] for r in records[:2]] == [0x1B95, 0x1B9A], f"X20DI9371 in slot 1, X20DO9322 in slot 2: {records}")
check(all(r[9] == 254 for r in records[:5]), "every module in function model 254")
NONE = 0xFFFF
# (analog in, analog out, digital in, digital out) byte indexes per slot.
indexes = [tuple(r[4:8]) for r in records[:5]]
check(indexes == [
    (NONE, NONE, 0, NONE),  # DI: 12 inputs in bytes 0-1
    (NONE, NONE, NONE, 0),  # DO: 12 outputs in bytes 0-1
    (0, NONE, NONE, 2),     # counter word at byte 0, its reset bit in byte 2
    (2, NONE, NONE, 3),
    (NONE, 0, 2, 4),        # MM: period and two pulse widths, 6 status bits, 4 output bits
], f"data indexes: {indexes}")

# Product data and node number.
product = holding(0x1080, 8)
check(product[3] != 0, f"a product code: {product}")
check(holding(0x1180, 1) == [node], "node number")

# The X2X link runs: its cycle counter advances.
x2x = holding(0x11C0, 2)
time.sleep(0.2)
x2x_later = holding(0x11C0, 2)
check((x2x_later[0] << 16 | x2x_later[1]) > (x2x[0] << 16 | x2x[1]), f"X2X cycles advance: {x2x} then {x2x_later}")

# Power-on inputs: no switch, STOP or bridge error (DI bits 0-11, MM status bits 16-21); both
# counters (words 0 and 1) at 125 mm x 7000 counts/mm, wrapped to 16 bits.
di = client.read_discrete_inputs(0, count=22)
check(not di.isError() and list(di.bits[:22]) == [False] * 22, f"discrete inputs at power-on: {di}")
ir = client.read_input_registers(0, count=2)
check(not ir.isError() and ir.registers == [23032, 23032], f"counters at power-on: {ir}")

# The watchdog, set as a controller that feeds it by writes only: 200 ms, mode 0xC2, reset.
write(0x1040, 200)
write(0x1043, 0xC2)
write(0x1044, 0xC1)
wd = holding(0x1040, 4)
check(wd[0] == 200 and wd[2] == 0 and wd[3] == 0xC2, f"watchdog threshold, status, mode: {wd}")

# Outputs: the PWM period (analog out index 0 of slot 5: register 0x0800) and the spindle (DO
# bit 0: coil 0).
write(0x0800, 50)
check(not client.write_coil(0, True).isError(), "spindle on")
check(holding(0x0800, 1) == [50] and coil(0), "outputs read back")

# Only reads now: in mode 0xC2 they do not feed the watchdog, which expires, zeroes the outputs
# and sets error bit 5.
deadline = time.time() + 5
errors = 0
while time.time() < deadline:
    errors = holding(0x1187, 1)[0]
    if errors & WATCHDOG_EXPIRED:
        break
    time.sleep(0.05)
check(errors & WATCHDOG_EXPIRED, f"error bit 5 (watchdog expired) within 5 s: {errors:#x}")
check(holding(0x1042, 1)[0] != 0, "watchdog status: expired")
check(holding(0x0800, 1) == [0] and not coil(0), "outputs zeroed by the watchdog")

# The outputs stay off until a client resets the watchdog.
check(not client.write_coil(0, True).isError(), "a write while expired is answered")
check(not coil(0), "the outputs stay off while the watchdog is expired")
write(0x1044, 0xC1)
check(holding(0x1187, 1)[0] & WATCHDOG_EXPIRED == 0, "the reset clears error bit 5")
check(not client.write_coil(0, True).isError(), "spindle on again")
check(coil(0), "outputs written again after the reset")

# In mode 0xC1 any telegram feeds it: reads alone keep it from expiring.
write(0x1043, 0xC1)
deadline = time.time() + 0.6
while time.time() < deadline:
    check(holding(0x1187, 1)[0] & WATCHDOG_EXPIRED == 0, "reads feed the watchdog in mode 0xC1")
    time.sleep(0.05)
check(coil(0), "the output stands while reads feed the watchdog")

# Outside the process image and the bus controller's registers: exception 2.
err = client.read_input_registers(2, count=1)
check(err.isError() and err.exception_code == 2, f"beyond the analog input image is exception 2: {err}")
write(0x1043, 0xC0)
client.close()
print("ok")
