#!/usr/bin/env python3
"""The server under many clients (issue 26): N client processes against one server.

  python3 bench/load/load_bench.py [--clients 1,8,32] [--seconds 5] [--mix call]
      [--payload 2] [--client pnp|node] [--build build]
      [--url URL --server-pid PID [--namespace URI]]   (a server started by you, e.g.
                                                       open62541's, instead of ours)
      [--open62541 EXE]                                 (open62541's server in the same run:
                                                       bench/load/build_open62541_server.sh)
      [--event-loops N]                                 (our server's I/O threads)
      [--baseline EXE]                                  (another pnp_bench_server, e.g. the
                                                       previous commit's, in the same run)
      [--soak SECONDS [--sample-every 10]]
      [--sessions N [--per-process 250]]
      [--repeat N]                                      (N repetitions, rotated order,
                                                       median ratios at the end)
      [--json OUT]

Per client count, one round: the server (ours: pnp_bench_server --ticker 5, started here;
else the one at --url) and N client processes (pnp_bench_load_client, or node-opcua's with
--client node: bench/load/node_load_client.js), all starting at the same instant, each
running the mix for --seconds and checking every response (see load_client.cpp). Reported:
calls/s (sum over clients), latency median and p99 (merged histograms), the server's CPU per
call (utime + stime from /proc/PID/stat over the round / calls), its RSS and open file
descriptors after the round, and errors, mismatches (a response that is not the request's),
notifications out of sequence (publish mix).

--soak SECONDS: one round of --clients (the first count) for that long; the server's RSS and
descriptors are sampled every --sample-every seconds and their growth from the first tenth
to the last tenth of the run is reported (the issue's soak: 1 hour, no growth, nothing lost,
nothing out of sequence).

--sessions N: N idle sessions (each with a subscription and a monitored item) held by
ceil(N / --per-process) processes; reported: the server's RSS per idle session, and the p99
of one client's Read loop with the N sessions open next to the same loop before they were
(our server runs with --max-sessions N + 100).

Processes are stopped by PID (SIGTERM, then SIGKILL after 3 s); every wait has a deadline.
Loopback only. Not a test: nothing here runs in CI.
"""
import argparse
import json
import statistics
import os
import signal
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TICK = os.sysconf("SC_CLK_TCK")


def proc_cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime


def proc_rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def proc_fds(pid):
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return -1


def stop(p, grace=3.0):
    if p.poll() is not None:
        return
    p.send_signal(signal.SIGTERM)
    try:
        p.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait(timeout=grace)


def percentile(hist, q):
    total = sum(hist.values())
    if total == 0:
        return float("nan")
    rank = max(1, int(-(-q * total // 1)))  # nearest rank
    seen = 0
    for us in sorted(hist):
        seen += hist[us]
        if seen >= rank:
            return us
    return max(hist)


def start_our_server(build, max_sessions=0, exe=None, event_loops=0):
    exe = exe or os.path.join(build, "bench", "pnp_bench_server")
    if not os.access(exe, os.X_OK):
        sys.exit(f"missing {exe}: build with -DPNP_BUILD_BENCH=ON")
    extra = ["--max-sessions", str(max_sessions)] if max_sessions else []
    if event_loops:
        extra += ["--event-loops", str(event_loops)]
    return start_server([exe, "--port", "0", "--ticker", "5"] + extra)


def read_line(p, prefix, deadline):
    """The first line of p's stdout (a binary pipe) that starts with prefix, or None at the
    deadline or EOF. Reads the pipe itself (os.read): nothing hides in a Python buffer."""
    import select
    pending = b""
    while True:
        while b"\n" in pending:
            line, pending = pending.split(b"\n", 1)
            if line.decode(errors="replace").startswith(prefix):
                return line.decode(errors="replace")
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([p.stdout], [], [], left)[0]:
            return None
        chunk = os.read(p.stdout.fileno(), 4096)
        if not chunk:
            return None
        pending += chunk


def start_server(argv):
    """Starts a server that prints "listening on URL"; (process, URL)."""
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, bufsize=0)
    line = read_line(p, "listening on ", time.monotonic() + 10)
    if line:
        return p, line.split()[-1]
    stop(p)
    sys.exit(f"{argv[0]} did not start")


def free_port():
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_o6_server(exe):
    return start_server([exe, str(free_port())])


def client_argv(args, url, i, start_at, seconds):
    common = ["--mix", args.mix, "--seconds", str(seconds), "--payload",
              str(args.payload), "--id", str(i), "--namespace", args.namespace,
              "--start-at", str(start_at)]
    if args.client == "node":
        return ["node", os.path.join(ROOT, "bench", "load", "node_load_client.js"), url] + common
    return [os.path.join(args.build, "bench", "load", "pnp_bench_load_client"), url] + common


def round_(args, url, server_pid, clients, seconds, sample_every=None):
    start_at = time.clock_gettime_ns(time.CLOCK_MONOTONIC) + int(
        (1.0 + 0.05 * clients) * 1e9) + (3_000_000_000 if args.client == "node" else 0)
    procs = [subprocess.Popen(client_argv(args, url, i, start_at, seconds), stdout=subprocess.PIPE,
                              text=True) for i in range(clients)]
    # CPU from the common start to the end of the last client.
    while time.clock_gettime_ns(time.CLOCK_MONOTONIC) < start_at:
        time.sleep(0.001)
    cpu0 = proc_cpu_seconds(server_pid)
    samples = []
    deadline = time.monotonic() + seconds + 60 + clients
    next_sample = time.monotonic()
    while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
        if sample_every and time.monotonic() >= next_sample:
            samples.append((time.monotonic(), proc_rss_kib(server_pid), proc_fds(server_pid)))
            next_sample += sample_every
        time.sleep(0.05)
    cpu1 = proc_cpu_seconds(server_pid)
    hist, calls, errors, mismatches, notes, order, failed, elapsed = {}, 0, 0, 0, 0, 0, 0, 0.0
    for p in procs:
        if p.poll() is None:
            stop(p)
            failed += 1
            continue
        # node-opcua may print its own lines on stdout: the result is the last JSON line.
        out = [l for l in p.stdout.read().splitlines() if l.startswith('{"id"')]
        r = json.loads(out[-1]) if out else {"error": "no output"}
        if "error" in r:
            failed += 1
            continue
        calls += r["calls"]
        errors += r["errors"]
        mismatches += r["mismatches"]
        notes += r["notifications"]
        order += r["outOfOrder"]
        elapsed = max(elapsed, r["seconds"])
        for us, n in r["hist"]:
            hist[us] = hist.get(us, 0) + n
    return {
        "clients": clients, "calls": calls, "callsPerSecond": calls / elapsed if elapsed else 0,
        "medianUs": percentile(hist, 0.5), "p99Us": percentile(hist, 0.99),
        "serverCpuPerCallUs": (cpu1 - cpu0) * 1e6 / calls if calls else float("nan"),
        "serverRssKiB": proc_rss_kib(server_pid), "serverFds": proc_fds(server_pid),
        "errors": errors, "mismatches": mismatches, "notifications": notes,
        "outOfOrder": order, "failedClients": failed, "samples": samples,
    }


def many_sessions(args, url, pid):
    probe = dict(vars(args))
    probe_args = argparse.Namespace(**{**probe, "mix": "read", "seconds": 3})
    before = round_(probe_args, url, pid, 1, 3)
    rss0 = proc_rss_kib(pid)
    exe = os.path.join(args.build, "bench", "load", "pnp_bench_load_client")
    holders, left, i = [], args.sessions, 0
    hold = 60 + args.sessions / 50
    while left > 0:
        k = min(left, args.per_process)
        holders.append(subprocess.Popen(
            [exe, url, "--idle-sessions", str(k), "--seconds", str(hold), "--id", str(i),
             "--namespace", args.namespace], stdout=subprocess.PIPE, bufsize=0))
        left -= k
        i += 1
    opened = 0
    try:
        deadline = time.monotonic() + 60 + args.sessions / 20
        for h in holders:
            line = read_line(h, "ready ", deadline)
            if line:
                opened += int(line.split()[1])
        t_open = time.monotonic()
        rss1 = proc_rss_kib(pid)
        after = round_(probe_args, url, pid, 1, 3) if opened == args.sessions else None
    finally:
        for h in holders:
            stop(h)
    r = {"sessions": opened, "wanted": args.sessions,
         "bytesPerSession": (rss1 - rss0) * 1024 / max(1, opened),
         "p99Before": before["p99Us"], "p99With": after["p99Us"] if after else None,
         "medianBefore": before["medianUs"], "medianWith": after["medianUs"] if after else None}
    print(f"{opened} of {args.sessions} idle sessions open; server RSS {rss0 / 1024:.1f} -> "
          f"{rss1 / 1024:.1f} MiB = {r['bytesPerSession'] / 1024:.1f} KiB per session")
    if after:
        print(f"Read loop of one client: median {before['medianUs']} -> {after['medianUs']} µs, "
              f"p99 {before['p99Us']} -> {after['p99Us']} µs "
              f"(ratio {after['p99Us'] / max(1, before['p99Us']):.2f}, target ≤ 2)")
    return r


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clients", default="1,8,32")
    ap.add_argument("--seconds", type=float, default=5)
    ap.add_argument("--mix", default="call",
                    choices=["call", "read", "write", "mixed", "publish"])
    ap.add_argument("--payload", type=int, default=2)
    ap.add_argument("--client", default="pnp", choices=["pnp", "node"])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--url")
    ap.add_argument("--server-pid", type=int)
    ap.add_argument("--namespace", default="urn:pnp:demo")
    ap.add_argument("--open62541")
    ap.add_argument("--baseline")
    ap.add_argument("--event-loops", type=int, default=0)
    ap.add_argument("--soak", type=float)
    ap.add_argument("--sample-every", type=float, default=10)
    ap.add_argument("--sessions", type=int)
    ap.add_argument("--per-process", type=int, default=250)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--json")
    args = ap.parse_args()
    if not 1 <= args.repeat <= 100:
        sys.exit("--repeat: 1 .. 100")
    counts = [int(c) for c in args.clients.split(",") if c]
    if not counts or min(counts) < 1 or max(counts) > 2000:
        sys.exit("--clients: counts between 1 and 2000")
    if bool(args.url) != bool(args.server_pid):
        sys.exit("--url and --server-pid go together")
    server = None
    url, pid = args.url, args.server_pid
    if args.sessions is not None and not 1 <= args.sessions <= 100000:
        sys.exit("--sessions: 1 .. 100000")
    if not url:
        server, url = start_our_server(args.build, (args.sessions or 0) + 100 if args.sessions else 0,
                                       None, args.event_loops)
        pid = server.pid
    o6 = o6_url = None
    if args.open62541:
        if args.soak:
            sys.exit("--open62541 is for the table, not --soak")
        o6, o6_url = start_o6_server(args.open62541)
    base = base_url = None
    if args.baseline:
        if args.soak or args.sessions:
            sys.exit("--baseline is for the table")
        base, base_url = start_our_server(args.build, 0, args.baseline)
    results = []
    try:
        print(f"server {url} (pid {pid}), client {args.client}, mix {args.mix}, "
              f"payload {args.payload} B, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}")
        if args.sessions:
            results.append(many_sessions(args, url, pid))
        elif args.soak:
            r = round_(args, url, pid, counts[0], args.soak, args.sample_every)
            s = r["samples"]
            tenth = max(1, len(s) // 10)
            first, last = s[:tenth], s[-tenth:]
            avg = lambda xs, k: sum(x[k] for x in xs) / len(xs) if xs else float("nan")
            r["rssGrowthKiB"] = avg(last, 1) - avg(first, 1)
            r["fdGrowth"] = avg(last, 2) - avg(first, 2)
            results.append(r)
            print(f"soak {args.soak:.0f} s, {counts[0]} clients: {r['callsPerSecond']:.0f} calls/s, "
                  f"RSS growth {r['rssGrowthKiB']:.0f} KiB, fd growth {r['fdGrowth']:.1f}, "
                  f"errors {r['errors']}, mismatches {r['mismatches']}, "
                  f"out of sequence {r['outOfOrder']} of {r['notifications']} notifications")
        else:
            print(("    " if o6 or base else "") + " clients |   calls/s |  median µs |    p99 µs | server CPU/call µs | RSS MiB "
                  "| fds | errors mism. order")
            def row(label, n, r):
                print(f"{label}{n:7d} | {r['callsPerSecond']:9.0f} | {r['medianUs']:10.0f} | "
                      f"{r['p99Us']:9.0f} | {r['serverCpuPerCallUs']:18.1f} | "
                      f"{r['serverRssKiB'] / 1024:7.1f} | {r['serverFds']:3d} | "
                      f"{r['errors']} {r['mismatches']} {r['outOfOrder']}"
                      + (f" of {r['notifications']} notifications" if args.mix == "publish" else "")
                      + (f"  ({r['failedClients']} clients failed)" if r["failedClients"] else ""),
                      flush=True)

            # Each repetition runs the servers in a rotated order (no server always first
            # after a pause); the ratios' medians over the repetitions are printed at the end.
            servers = [("pnp ", "pnp", url, pid)]
            if base:
                servers.append(("base", "baseline", base_url, base.pid))
            if o6:
                servers.append(("o6  ", "open62541", o6_url, o6.pid))
            ratios = {}  # (clients, other) -> [(calls/s, CPU per call, median, p99)]
            for rep in range(args.repeat):
                if args.repeat > 1:
                    print(f"-- repetition {rep + 1} of {args.repeat}", flush=True)
                for n in counts:
                    k = rep % len(servers)
                    got = {}
                    for label, name, u, p in servers[k:] + servers[:k]:
                        q = round_(args, u, p, n, args.seconds)
                        q["server"] = name if name != "pnp" or server else "given"
                        q["repetition"] = rep
                        results.append(q)
                        row(label if len(servers) > 1 else "", n, q)
                        got[name] = q
                    r = got["pnp"]
                    for _, name, _, _ in servers[1:]:
                        q = got[name]
                        x = (r["callsPerSecond"] / max(1, q["callsPerSecond"]),
                             r["serverCpuPerCallUs"] / q["serverCpuPerCallUs"],
                             r["medianUs"] / max(1, q["medianUs"]), r["p99Us"] / max(1, q["p99Us"]))
                        ratios.setdefault((n, name), []).append(x)
                        print(f"     ratio pnp/{name}: calls/s {x[0]:.2f}, CPU per call {x[1]:.2f}"
                              f", median {x[2]:.2f}, p99 {x[3]:.2f}", flush=True)
            if args.repeat > 1 and ratios:
                print(f"medians over {args.repeat} repetitions:")
                for (n, name), xs in ratios.items():
                    med = [statistics.median(x[i] for x in xs) for i in range(4)]
                    print(f"  {n:4d} clients, pnp/{name}: calls/s {med[0]:.2f} "
                          f"(min {min(x[0] for x in xs):.2f}, max {max(x[0] for x in xs):.2f})"
                          f", CPU per call {med[1]:.2f}, median {med[2]:.2f}, p99 {med[3]:.2f}",
                          flush=True)
    finally:
        if server:
            stop(server)
        if o6:
            stop(o6)
        if base:
            stop(base)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    bad = any(r.get("errors") or r.get("mismatches") or r.get("outOfOrder") or
              r.get("failedClients") or r.get("sessions", 0) != r.get("wanted", r.get("sessions", 0))
              for r in results)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
