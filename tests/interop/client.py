"""A pymodbus client (an implementation nobody here wrote) drives `pkm-plc io-sim` over TCP.

Usage: client.py HOST:PORT. Exits 0 when every check holds, else 1 with the failing check."""
import sys
import time

from pymodbus.client import ModbusTcpClient


def check(condition, what):
    if not condition:
        print(f"FAILED: {what}")
        sys.exit(1)


host, port = sys.argv[1].rsplit(":", 1)
client = ModbusTcpClient(host, port=int(port))
check(client.connect(), "connect")
di = client.read_discrete_inputs(0, count=18)
check(not di.isError() and list(di.bits[:18]) == [False] * 18, f"discrete inputs at power-on: {di}")
ir = client.read_input_registers(0, count=2)
check(not ir.isError() and ir.registers == [23032, 23032], f"counters at power-on: {ir}")
check(not client.write_register(0, 50).isError(), "write the PWM period")
check(not client.write_register(2, 32767).isError(), "left motor at full duty")
time.sleep(0.3)
check(not client.write_register(2, 0).isError(), "left motor off")
hr = client.read_holding_registers(0, count=3)
check(not hr.isError() and hr.registers == [50, 0, 0], f"holding registers read back: {hr}")
time.sleep(0.2)
ir = client.read_input_registers(0, count=2)
check(ir.registers[0] != 23032 and ir.registers[1] == 23032, f"only the left counter moved: {ir.registers}")
check(not client.write_coils(12, [True]).isError(), "counter reset coil")
ir = client.read_input_registers(0, count=1)
value = ir.registers[0] - 65536 if ir.registers[0] >= 32768 else ir.registers[0]
check(abs(value) < 100, f"the reset counter reads {value}")
# The packed process image in one read/write-multiple-registers request (function code 23):
# outputs at 8192 (coils 0-15, 16-17, holding registers 0-2), inputs at 4096 (discrete inputs
# 0-15, 16-17, input registers 0-1).
rw = client.readwrite_registers(read_address=4096, read_count=4, write_address=8192, values=[0, 0, 50, 0, 0])
check(not rw.isError() and rw.registers[:2] == [0, 0] and len(rw.registers) == 4, f"packed image: {rw}")
ir = client.read_input_registers(0, count=2)
check(rw.registers[3] == ir.registers[1], f"the image's right counter {rw.registers[3]} is input register 1 {ir.registers[1]}")
co = client.read_coils(12, count=1)
check(not co.isError() and not co.bits[0], f"the image cleared the counter reset coil: {co}")
err = client.read_input_registers(2, count=1)
check(err.isError() and err.exception_code == 2, f"an unmapped address is exception 2: {err}")
client.close()
print("ok")
