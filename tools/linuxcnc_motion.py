#!/usr/bin/python3.11
"""LinuxCNC 2.9's own motion of a G-code program, recorded in its simulator.

Starts LinuxCNC (Debian's `linuxcnc-uspace`) on a simulated XYZ machine with trivial kinematics,
every axis (and joint) bounded by the speed and acceleration given — as a lab would configure
LinuxCNC for one of our machines, which knows nothing of its kinematics —, homes it where it
stands, runs the program to its end, and writes the commanded position of every servo period
(1 ms) to OUT, one `x y z` line a period, from the first period that moves to the last.

    tools/linuxcnc_motion.py --vel 20 --acc 100 PROGRAM.ngc OUT.txt

It runs in real time (a 60 s program takes a minute) and needs nothing but the Debian package
(its Python module is the system's Python 3.11's). The benchmark `cargo run --release --example
planner_vs_linuxcnc -- --measure` runs it on its programs and takes the motion through the
machine's inverse kinematics.
"""

import os
import shutil
import subprocess
import sys
import tempfile
import time

INI = """[EMC]
VERSION = 1.1
MACHINE = pkm-plc-benchmark
DEBUG = 0
[DISPLAY]
DISPLAY = {script} --display
CYCLE_TIME = 0.010
POSITION_OFFSET = RELATIVE
POSITION_FEEDBACK = COMMANDED
MAX_FEED_OVERRIDE = 1.0
[TASK]
TASK = milltask
CYCLE_TIME = 0.001
[RS274NGC]
PARAMETER_FILE = sim.var
[EMCMOT]
EMCMOT = motmod
COMM_TIMEOUT = 1.0
BASE_PERIOD = 0
SERVO_PERIOD = 1000000
[EMCIO]
EMCIO = io
CYCLE_TIME = 0.100
TOOL_TABLE = sim.tbl
[HAL]
HALFILE = sim.hal
[TRAJ]
COORDINATES = X Y Z
LINEAR_UNITS = mm
ANGULAR_UNITS = degree
DEFAULT_LINEAR_VELOCITY = {vel}
MAX_LINEAR_VELOCITY = {path_vel}
DEFAULT_LINEAR_ACCELERATION = {acc}
MAX_LINEAR_ACCELERATION = {path_acc}
POSITION_FILE = position.txt
[KINS]
KINEMATICS = trivkins
JOINTS = 3
"""

AXIS = """[AXIS_{name}]
MAX_VELOCITY = {vel}
MAX_ACCELERATION = {acc}
MIN_LIMIT = -1000
MAX_LIMIT = 1000
[JOINT_{joint}]
TYPE = LINEAR
HOME = 0
MAX_VELOCITY = {vel}
MAX_ACCELERATION = {acc}
MIN_LIMIT = -1000
MAX_LIMIT = 1000
FERROR = 100
MIN_FERROR = 100
HOME_OFFSET = 0
HOME_SEARCH_VEL = 0
HOME_LATCH_VEL = 0
HOME_SEQUENCE = 0
"""

HAL = """loadrt [KINS]KINEMATICS
loadrt [EMCMOT]EMCMOT base_period_nsec=[EMCMOT]BASE_PERIOD servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS
loadrt sampler depth=16000 cfg=fff
addf motion-command-handler servo-thread
addf motion-controller servo-thread
addf sampler.0 servo-thread
net Xpos joint.0.motor-pos-cmd => joint.0.motor-pos-fb sampler.0.pin.0
net Ypos joint.1.motor-pos-cmd => joint.1.motor-pos-fb sampler.0.pin.1
net Zpos joint.2.motor-pos-cmd => joint.2.motor-pos-fb sampler.0.pin.2
setp sampler.0.enable 1
net estop-loop iocontrol.0.user-enable-out iocontrol.0.emc-enable-in
net tool-prep-loop iocontrol.0.tool-prepare iocontrol.0.tool-prepared
net tool-change-loop iocontrol.0.tool-change iocontrol.0.tool-changed
"""


def display():
    """LinuxCNC's display: machine on, home, run the program, wait for its end, quit."""
    import linuxcnc

    program, samples = os.environ["PKM_PROGRAM"], os.environ["PKM_SAMPLES"]
    sampler = subprocess.Popen(["halsampler", "-c", "0"], stdout=open(samples, "w"))
    s, c = linuxcnc.stat(), linuxcnc.command()

    def wait(cond, what, timeout=30.0):
        end = time.time() + timeout
        checked = time.time()
        while time.time() < end:
            s.poll()
            if cond():
                return
            if time.time() - checked >= 1.0:
                # LinuxCNC's task gone (seen once), its status stands still: say so, not wait.
                checked = time.time()
                if subprocess.run(["pgrep", "-x", "milltask"], capture_output=True).returncode != 0:
                    raise SystemExit(f"linuxcnc_motion: LinuxCNC's task ended while waiting for {what}")
            time.sleep(0.01)
        raise SystemExit(f"linuxcnc_motion: timed out waiting for {what}")

    wait(lambda: s.task_state != 0, "the task")
    c.state(linuxcnc.STATE_ESTOP_RESET)
    c.state(linuxcnc.STATE_ON)
    wait(lambda: s.task_state == linuxcnc.STATE_ON, "machine on")
    c.mode(linuxcnc.MODE_MANUAL)
    c.home(-1)
    wait(lambda: all(s.homed[:3]), "homing")
    c.mode(linuxcnc.MODE_AUTO)
    wait(lambda: s.task_mode == linuxcnc.MODE_AUTO, "auto mode")
    c.program_open(program)
    c.auto(linuxcnc.AUTO_RUN, 0)
    wait(lambda: s.interp_state != linuxcnc.INTERP_IDLE, "the program's start")
    # The end: the interpreter idle, nothing queued and the tool still, for a second on end (a
    # long program's interpreter can be idle with an empty queue for a moment while task reads
    # ahead, on a busy machine for longer).
    still_since = [None]

    def ended():
        if s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.current_vel == 0.0:
            still_since[0] = still_since[0] or time.time()
            return time.time() - still_since[0] >= 1.0
        still_since[0] = None
        return False

    wait(ended, "the program's end", 7200.0)
    time.sleep(0.2)
    sampler.terminate()
    sampler.wait()
    # The motion is whole: the recorder may use it.
    open(os.environ["PKM_DONE"], "w").close()
    c.state(linuxcnc.STATE_OFF)


def main():
    if "--display" in sys.argv:
        display()
        return
    args = sys.argv[1:]
    try:
        vel = float(args[args.index("--vel") + 1])
        acc = float(args[args.index("--acc") + 1])
        program, out = [a for a in args if not a.startswith("--") and a not in (str(vel), str(acc))][-2:]
    except (ValueError, IndexError):
        print(__doc__)
        sys.exit(2)
    if shutil.which("linuxcnc") is None:
        sys.exit("linuxcnc_motion: no linuxcnc here (apt-get install linuxcnc-uspace)")
    with tempfile.TemporaryDirectory() as d:
        ini = INI.format(
            script=os.path.abspath(__file__),
            vel=vel,
            acc=acc,
            path_vel=10 * vel,
            path_acc=10 * acc,
        )
        for joint, name in enumerate("XYZ"):
            ini += AXIS.format(name=name, joint=joint, vel=vel, acc=acc)
        for name, text in [("sim.ini", ini), ("sim.hal", HAL), ("sim.tbl", "T1 P1 Z0 D1\n"), ("sim.var", "")]:
            with open(os.path.join(d, name), "w") as f:
                f.write(text)
        raw = os.path.join(d, "samples.txt")
        # rtapi_app refuses to run as root unless told which user to fall back to.
        os.chmod(d, 0o777)
        env = dict(
            os.environ,
            PKM_PROGRAM=os.path.abspath(program),
            PKM_SAMPLES=raw,
            PKM_DONE=os.path.join(d, "done"),
            RTAPI_UID=os.environ.get("RTAPI_UID", "65534" if os.getuid() == 0 else str(os.getuid())),
            RTAPI_FIFO_PATH=os.path.join(d, ".rtapi_fifo"),
        )
        run = subprocess.run(["linuxcnc", os.path.join(d, "sim.ini")], cwd=d, env=env, capture_output=True, text=True)
        if not os.path.exists(os.path.join(d, "done")):
            sys.exit(f"linuxcnc_motion: LinuxCNC did not run the program to its end:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}")
        rows = []
        with open(raw) as f:
            for line in f:
                if line.strip() == "overrun":
                    # halsampler marks each gap in the samples so: the motion's time is lost.
                    sys.exit("linuxcnc_motion: samples were lost (the machine was too busy for halsampler): run it on a quiet machine")
                v = line.split()
                if len(v) >= 3:
                    rows.append(v[-3:])
        # From the first period that moves to the last.
        moving = [i for i in range(1, len(rows)) if rows[i] != rows[i - 1]]
        if not moving:
            sys.exit("linuxcnc_motion: the program did not move")
        with open(out, "w") as f:
            for r in rows[moving[0] - 1 : moving[-1] + 1]:
                f.write(" ".join(r) + "\n")
        print(f"{program}: {(moving[-1] - moving[0] + 1) / 1000.0:.3f} s of motion")


if __name__ == "__main__":
    main()
