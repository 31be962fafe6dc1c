#!/usr/bin/env python3
"""Move time of a running world between the daemons of a cluster (docs/BENCHMARKS.md).

Starts --daemons physd processes of one cluster on loopback (tools/cluster.sh's layout, memory
only), loads a scene into a world on daemon 1, runs it at 60 Hz with a subscriber, and moves it
back and forth --moves times. For each move: the MoveWorld round trip (command to its reply),
and the time from the command to the subscriber's first frame after the move's tick (the new
owner's first frame); and whether the subscriber saw every tick once across the move.

    tools/move_bench.py [--scene pile_10k] [--moves 10] [--daemons 2] [--domain 91]

Needs build/ (physd and the Python module).
"""
import argparse
import contextlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(ROOT, "build", "client_sdk", "python"))
import physclient as pc  # noqa: E402


def start_daemons(n, domain, run_dir):
    procs = []
    for i in range(1, n + 1):
        d = os.path.join(run_dir, f"d{i}")
        os.makedirs(d, exist_ok=True)
        toml = os.path.join(d, "physd.toml")
        with open(toml, "w") as f:
            f.write(f"""[server]
name = "physd-{i}"
id = {i}
log_level = "info"
[cluster]
enabled = true
[dds]
domain = {domain}
config = "{ROOT}/configs/cyclonedds/loopback.xml"
[paths]
presets = "{ROOT}/configs/presets.json"
scenes = "{ROOT}/configs/scenes"
snapshots = "{d}/snapshots"
data = ""
""")
        log = open(os.path.join(d, "physd.log"), "w")
        procs.append(subprocess.Popen([os.path.join(ROOT, "build", "server", "physd"),
                                       "--config", toml], stdout=log, stderr=subprocess.STDOUT))
    return procs


@contextlib.contextmanager
def cluster(n, domain):
    """n daemons of a cluster (start_daemons) and a connected client that sees them all;
    everything stopped and removed at the end."""
    run_dir = tempfile.mkdtemp(prefix="physd_bench_")
    print(f"daemons' logs: {run_dir}/d<i>/physd.log")
    procs = start_daemons(n, domain, run_dir)
    try:
        with open(os.path.join(ROOT, "configs", "cyclonedds", "loopback.xml")) as f:
            xml = f.read()
        c = pc.Client(domain=domain, cyclone_xml=xml, connect_timeout=30.0,
                      request_timeout=60.0)
        c.connect()
        end = time.monotonic() + 20
        while len(c.daemons()) < n and time.monotonic() < end:
            time.sleep(0.05)
        yield c
        c.close()
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait()
        shutil.rmtree(run_dir, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pile_10k")
    ap.add_argument("--moves", type=int, default=10)
    ap.add_argument("--daemons", type=int, default=2)
    ap.add_argument("--domain", type=int, default=91)
    args = ap.parse_args()
    with cluster(args.daemons, args.domain) as c:
        w = c.create_world("moving", daemon=1)
        ids = w.load_scene(args.scene)
        print(f"{args.scene}: {len(ids.bodies)} bodies, {args.daemons} daemons")
        ticks = []
        lock = threading.Lock()

        def on_frame(f):
            with lock:
                ticks.append((time.monotonic(), f.tick))

        sub = w.subscribe(on_frame)
        end = time.monotonic() + 30
        while not ticks and time.monotonic() < end:
            time.sleep(0.01)
        w.run(60)
        time.sleep(1.0)
        acks, firsts = [], []
        here = 1
        for k in range(args.moves):
            to = here % args.daemons + 1
            t0 = time.monotonic()
            ack = w.move(to)
            t1 = time.monotonic()
            first = None
            while first is None and time.monotonic() < t0 + 30:
                with lock:
                    first = next((t for t, tick in ticks if tick > ack.tick), None)
                time.sleep(0.001)
            here = to
            if first is None:
                print(f"move {k + 1}: no frame after tick {ack.tick}")
                continue
            acks.append((t1 - t0) * 1e3)
            firsts.append((first - t0) * 1e3)
            time.sleep(0.5)
        w.pause()
        with lock:
            seen = [tick for _, tick in ticks]
        repeats = sum(1 for a, b in zip(seen, seen[1:]) if b == a)
        gaps = sum(1 for a, b in zip(seen, seen[1:]) if b > a + 1)
        backwards = sum(1 for a, b in zip(seen, seen[1:]) if b < a)
        print(f"MoveWorld reply: median {statistics.median(acks):.1f} ms, worst {max(acks):.1f} ms")
        print(f"command to the new owner's first frame: median {statistics.median(firsts):.1f} ms,"
              f" worst {max(firsts):.1f} ms ({len(firsts)} moves)")
        print(f"frames: {len(seen)}, ticks {seen[0]}..{seen[-1]}; repeated {repeats}, "
              f"skipped {gaps}, backwards {backwards}; duplicate replies {c.duplicate_replies()}")
        sub.close()


if __name__ == "__main__":
    main()
