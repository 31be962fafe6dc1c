#!/usr/bin/env python3
"""Takeover after SIGKILL and fencing after SIGSTOP (docs/BENCHMARKS.md "Standby and takeover").

Starts etcd (Debian's etcd-server) and four physd processes of one cluster on loopback, each
keeping its worlds in a data directory of its own, with the coordinator's default times. Daemons
1-3 form a ring (daemon i stands by for daemon i-1's worlds, 1 for 3's); daemon 4 holds the
twins and is never stopped. The victim daemon holds two worlds: `running` (the scene, at 60 Hz,
with a subscriber, edited by the client: the takeover time) and `stepped` (a pile stepped and
edited alike with its twin on daemon 4: the state check).

Each SIGKILL round: edits acknowledged on both worlds, then the victim is killed; the takeover
time is from the kill to the subscriber's first frame of the new owner (a newer epoch); the
stepped world must then equal its twin bit for bit (every acknowledged edit present); the
killed daemon is started again and must stand down. Right after the kill an edit is sent to
the world (in flight to a dead daemon: the SDK fails it, Disconnected, once the daemon's
liveliness lease lapses; its time is printed) and, at once after that failure, another (the
SDK holds it until a live daemon lists the world: it must be answered, and is counted as an
acknowledged edit). Each SIGSTOP round: the victim is stopped,
an edit is sent to it, the standby takes over, the victim is woken (SIGCONT): the edit must be
applied once (by the new owner: the twin check), and no frame of the old owner may reach the
subscriber after the new owner's (Subscription.stale_chunks).

    tools/takeover_bench.py [--kills 20] [--stops 20] [--scene box_stack] [--domain 93]

Needs build/ (physd and the Python module) and etcd.
"""
import argparse
import collections
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(ROOT, "build", "client_sdk", "python"))
import physclient as pc  # noqa: E402

RING = 3  # daemons 1..3 stand by for each other; daemon 4 holds the twins


class Cluster:
    def __init__(self, domain, port):
        self.dir = tempfile.mkdtemp(prefix="physd_takeover_")
        self.domain, self.port = domain, port
        self.url = f"http://127.0.0.1:{port}"
        peer = f"http://127.0.0.1:{port + 1}"
        self.etcd = subprocess.Popen(
            ["etcd", "--name", "bench", "--data-dir", os.path.join(self.dir, "etcd"),
             "--listen-client-urls", self.url, "--advertise-client-urls", self.url,
             "--listen-peer-urls", peer, "--initial-advertise-peer-urls", peer,
             "--initial-cluster", f"bench={peer}"],
            stdout=open(os.path.join(self.dir, "etcd.log"), "w"), stderr=subprocess.STDOUT)
        end = time.monotonic() + 10
        while time.monotonic() < end:
            try:
                socket.create_connection(("127.0.0.1", port), 0.2).close()
                break
            except OSError:
                time.sleep(0.05)
        self.procs = {}
        for i in range(1, RING + 2):
            self.start(i)

    def toml(self, i):
        d = os.path.join(self.dir, f"d{i}")
        os.makedirs(d, exist_ok=True)
        standby = f"standby = {i % RING + 1}\n" if i <= RING else ""
        path = os.path.join(d, "physd.toml")
        with open(path, "w") as f:
            f.write(f"""[server]
name = "physd-{i}"
id = {i}
log_level = "info"
status_period_s = 0.2
[cluster]
enabled = true
coordinator = "{self.url}"
{standby}[dds]
domain = {self.domain}
config = "{ROOT}/configs/cyclonedds/loopback.xml"
[paths]
presets = "{ROOT}/configs/presets.json"
scenes = "{ROOT}/configs/scenes"
data = "{d}/data"
""")
        return path

    def start(self, i):
        toml = self.toml(i)
        log = open(os.path.join(self.dir, f"d{i}", "physd.log"), "a")
        self.procs[i] = subprocess.Popen([os.path.join(ROOT, "build", "server", "physd"),
                                          "--config", toml], stdout=log, stderr=subprocess.STDOUT)

    def close(self):
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGCONT)
                p.terminate()
        for p in self.procs.values():
            p.wait()
        self.etcd.terminate()
        self.etcd.wait()
        if not os.environ.get("KEEP"):
            shutil.rmtree(self.dir, ignore_errors=True)


def state(w):
    return [(b.id, tuple(b.position), tuple(b.rotation), tuple(b.linear_velocity))
            for b in w.query_state().bodies]


def listed_on(c, world, daemon):
    """Whether `daemon` lists `world` as its own (one request, to it alone)."""
    try:
        return any(s.world == world and s.moving_to == 0
                   for s in c.list_worlds(daemon=daemon, timeout=1.0))
    except pc.Error:
        return False


def back(c, daemon, timeout=60.0):
    """Waits until `daemon` (restarted) sends status samples again."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(d.id == daemon and d.since_sample_s < 0.5 for d in c.daemons()):
            return True
        time.sleep(0.05)
    return False


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--stops", type=int, default=20)
    ap.add_argument("--scene", default="box_stack")
    ap.add_argument("--domain", type=int, default=93)
    ap.add_argument("--port", type=int, default=23970)
    args = ap.parse_args()
    cl = Cluster(args.domain, args.port)
    print(f"logs: {cl.dir}/d<i>/physd.log")
    try:
        with open(os.path.join(ROOT, "configs", "cyclonedds", "loopback.xml")) as f:
            xml = f.read()
        c = pc.Client(domain=args.domain, cyclone_xml=xml, connect_timeout=30.0,
                      request_timeout=20.0)
        c.connect()
        end = time.monotonic() + 20
        while len(c.daemons()) < RING + 1 and time.monotonic() < end:
            time.sleep(0.05)
        running = c.create_world("running", daemon=1)
        n = len(running.load_scene(args.scene).bodies)
        stepped = c.create_world("stepped", daemon=1)
        twin = c.create_world("twin", daemon=RING + 1)
        for w in (stepped, twin):
            w.load_scene("pyramid_20")
        ids = [b.id for b in stepped.query_state().bodies]
        time.sleep(1.0)  # registered with the coordinator
        frames = []
        lock = threading.Lock()

        def on_frame(f):
            with lock:
                frames.append((time.monotonic(), f.epoch, f.tick))

        sub = running.subscribe(on_frame)
        running.run(60)
        time.sleep(1.0)
        print(f"{args.scene}: {n} bodies at 60 Hz; pyramid_20 stepped beside its twin")

        def edit_both(k):
            body = ids[1 + k % 10]
            for w in (stepped, twin):
                w.set_velocity(body, (0.2 * (k % 3), 0.1, 0.0))
                w.step(5)

        def first_frame_after(epoch, since, timeout=20.0):
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                with lock:
                    t = next((t for t, e, _ in frames if e > epoch and t >= since), None)
                if t is not None:
                    return t
                time.sleep(0.001)
            return None

        owner = 1
        kills, stops, mismatches, stale, doubles = [], [], 0, 0, 0
        unanswered, unanswered_applied = 0, 0
        acked = 0
        # SIGKILL rounds: an edit sent right after the kill (in flight to a dead daemon: the
        # SDK fails it once the daemon's liveliness lease lapses), then one made right after
        # that failure (the SDK holds it until a live daemon lists the world).
        failed_after, carried_after, dead_edit_outcomes = [], [], []
        for k in range(args.kills + args.stops):
            kill = k < args.kills
            edit_both(k)
            acked += 2
            with lock:
                epoch = frames[-1][1] if frames else 0
            stale_before = sub.stale_chunks
            victim = cl.procs[owner]
            standby = owner % RING + 1
            t0 = time.monotonic()
            if kill:
                victim.kill()
                victim.wait()
            else:
                victim.send_signal(signal.SIGSTOP)
            pending, answer = None, []
            target = ids[2 + k % 5]
            if kill:
                def send_to_dead():
                    t1 = time.monotonic()
                    try:
                        stepped.set_velocity(target, (0.0, 0.0, 0.2))
                        answer.append("answered")
                    except pc.Error as e:
                        answer.append(type(e).__name__)
                    failed_after.append((time.monotonic() - t1) * 1e3)
                    t2 = time.monotonic()
                    try:
                        stepped.set_velocity(target, (0.0, 0.0, 0.4))
                        carried_after.append((time.monotonic() - t2) * 1e3)
                        answer.append("carried")
                    except pc.Error as e:
                        answer.append(type(e).__name__)
                pending = threading.Thread(target=send_to_dead)
                pending.start()
            else:
                # An edit on its way to the stopped owner (the SDK sends it there).
                def send():
                    try:
                        answer.append(stepped.set_velocity(target, (0.0, 0.0, 0.3)))
                    except pc.Error as e:
                        answer.append(e)
                pending = threading.Thread(target=send)
                pending.start()
            t = first_frame_after(epoch, t0)
            if t is None:
                print(f"round {k + 1}: no frame from daemon {standby}")
                break
            (kills if kill else stops).append((t - t0) * 1e3)
            print(f"round {k + 1}: {'SIGKILL' if kill else 'SIGSTOP'} daemon {owner}, daemon "
                  f"{standby}'s first frame after {(t - t0) * 1e3:.0f} ms", flush=True)
            # The SDK routes a world's commands by the daemons' status: the new owner's (sent
            # at the takeover) may come after its first frame. One round trip to it first.
            end = time.monotonic() + 10
            while not listed_on(c, stepped.id, standby) and time.monotonic() < end:
                time.sleep(0.01)
            if kill:
                pending.join()
                dead_edit_outcomes.append(tuple(answer))
                if answer[-1] == "carried":
                    acked += 1
                    twin.set_velocity(target, (0.0, 0.0, 0.4))
                else:
                    print(f"round {k + 1}: the edits after the kill got {answer}", flush=True)
                cl.start(owner)
            else:
                victim.send_signal(signal.SIGCONT)
                pending.join()
                if not isinstance(answer[0], pc.Error):
                    acked += 1
                    twin.set_velocity(target, (0.0, 0.0, 0.3))
                else:
                    # No answer: applied or not (the signal lands a moment after kill()
                    # returns; an edit journaled then, unacknowledged, is in the files the
                    # standby replays). The paused world says which: its velocity is the edit's.
                    unanswered += 1
                    v = next(b.linear_velocity for b in stepped.query_state().bodies
                             if b.id == target)
                    if tuple(v) == (0.0, 0.0, 0.3):
                        unanswered_applied += 1
                        twin.set_velocity(target, (0.0, 0.0, 0.3))
                    print(f"round {k + 1}: the edit got {answer[0]!r}; applied: "
                          f"{tuple(v) == (0.0, 0.0, 0.3)}", flush=True)
            for w in (stepped, twin):
                w.step(3)
            if state(stepped) != state(twin):
                mismatches += 1
            # The old owner (restarted, or woken) is back and has stood down: it lists neither
            # world; it stands by for the new owner's worlds in a later round.
            if not back(c, owner):
                print(f"round {k + 1}: daemon {owner} did not come back")
                break
            end = time.monotonic() + 20
            while ((listed_on(c, running.id, owner) or listed_on(c, stepped.id, owner))
                   and time.monotonic() < end):
                time.sleep(0.05)
            if listed_on(c, running.id, owner) or listed_on(c, stepped.id, owner):
                doubles += 1
            time.sleep(0.5)
            stale += sub.stale_chunks - stale_before
            owner = standby
        running.pause()

        def line(name, xs):
            if xs:
                print(f"{name}: median {statistics.median(xs):.0f} ms, worst {max(xs):.0f} ms "
                      f"({len(xs)} rounds)")
        line("SIGKILL -> the new owner's first frame", kills)
        line("SIGSTOP -> the new owner's first frame", stops)
        print(f"edits sent to a stopped owner and not answered (outcome unknown to the client) "
              f"{unanswered}, of them applied {unanswered_applied}")
        line("SIGKILL -> an edit on its way to the dead owner fails", failed_after)
        line("then an edit made at once -> answered by the new owner", carried_after)
        print(f"edits after a kill: {dict(collections.Counter(dead_edit_outcomes))}")
        print(f"acknowledged edits {acked}; state mismatches with the twin {mismatches} "
              f"(an acknowledged edit lost or applied twice shows as one); stale chunks after "
              f"the new owner's {stale}; old owners still listing a world {doubles}; duplicate "
              f"replies {c.duplicate_replies()}")
        sub.close()
        c.close()
    finally:
        cl.close()


if __name__ == "__main__":
    main()
