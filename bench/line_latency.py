#!/usr/bin/env python3
"""Round-trip latency of a byte line between two SCHED_FIFO processes: a pseudo-terminal pair
(what a serial port test opens) against a Unix stream socket pair (the simulated robot's load-cell
line, taut_simrig::LoadCellLine). An echo process at priority 80 answers 8-byte requests from a
client at priority 79 every 5 ms. Run as root, beside the load to measure under:

    python3 bench/line_latency.py pty 60
    python3 bench/line_latency.py socket 60
"""
import os
import select
import socket
import sys
import time
import tty

kind, seconds = sys.argv[1], float(sys.argv[2])
if kind == "pty":
    m, s = os.openpty()
    tty.setraw(s)
    tty.setraw(m)
elif kind == "socket":
    a, b = socket.socketpair()
    m, s = a.fileno(), b.fileno()
else:
    sys.exit("kind: pty or socket")
pid = os.fork()
if pid == 0:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(80))
    while True:
        os.write(m, os.read(m, 64))
os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(79))
lat = []
end = time.time() + seconds
while time.time() < end:
    t0 = time.monotonic()
    os.write(s, b"12345678")
    got = b""
    while len(got) < 8:
        r, _, _ = select.select([s], [], [], 5)
        if not r:
            break
        got += os.read(s, 64)
    lat.append(time.monotonic() - t0)
    time.sleep(0.005)
os.kill(pid, 9)
lat.sort()
n = len(lat)
print(
    f"{kind}: {n} round trips, median {lat[n // 2] * 1e3:.2f} ms, p99 {lat[int(n * 0.99)] * 1e3:.2f} ms, "
    f"p99.9 {lat[int(n * 0.999)] * 1e3:.2f} ms, max {lat[-1] * 1e3:.1f} ms, over 50 ms: {sum(x > 0.05 for x in lat)}"
)
