#!/usr/bin/env python3
# Spawn -> first accepted TCP connection of `pnp ua serve [ARGS]`, median of RUNS starts
# (docs/nodeset_loading.md: start-up with and without NodeSet2 XML).
# usage: bench/listen_time.py PNP_BINARY PORT RUNS [serve args...]
import socket, subprocess, sys, time, statistics
binary, port, runs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
extra = sys.argv[4:]
times = []
for i in range(runs):
    t0 = time.perf_counter()
    p = subprocess.Popen([binary, "ua", "serve", "--port", str(port), "--no-register"] + extra,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.05).close()
            break
        except OSError:
            if p.poll() is not None: sys.exit("server exited")
            time.sleep(0.0005)
    times.append((time.perf_counter() - t0) * 1000)
    p.terminate(); p.wait()
print("spawn -> accepting: median %.1f ms, min %.1f, max %.1f (%d runs) %s" % (
    statistics.median(times), min(times), max(times), runs, " ".join(extra)))
