#!/usr/bin/env python3
"""physclient (the Python bindings of the client SDK) against the physd binary.

The module starts a physd of its own: a temporary config with a DDS domain from this process's
id (150..229), configs/cyclonedds/loopback.xml with a discovery tag of this process (so that
tests running in parallel never see each other's daemons), the source tree's presets and
scenes, snapshot and data folders in a temporary folder; it is stopped with SIGTERM at the end
and must exit cleanly.

    Bindings       the API end to end: physics (free fall, a resting box, forces, joints),
                   run / pause, subscriptions, snapshots, typed errors
    ExampleScript  examples/drop_boxes.py against the same kind of daemon
    Cluster        three daemons of a domain ([cluster]): worlds placed, reached, listed,
                   each command answered once

Environment (ctest sets it: client_sdk/python/CMakeLists.txt): PYTHONPATH with the built
module, PHYSD_BINARY, PHYS_SOURCE_DIR.
"""
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
import unittest
import weakref

SOURCE_DIR = os.environ.get("PHYS_SOURCE_DIR") or os.path.abspath(
    os.path.join(os.path.dirname(__file__), "..", "..", ".."))
PHYSD = os.environ.get("PHYSD_BINARY") or os.path.join(SOURCE_DIR, "build", "server", "physd")
EXAMPLE = os.path.join(SOURCE_DIR, "client_sdk", "python", "examples", "drop_boxes.py")
SERVER_NAME = "physd-python"

import physclient as pc  # noqa: E402  (PYTHONPATH: the build folder)

G = 9.81
DT = 1.0 / 60


class Daemon:
    """physd with a config of its own, stopped with SIGTERM."""

    def __init__(self, name, domain=None, server_toml="", extra_toml=""):
        self.dir = tempfile.mkdtemp(prefix="physclient_py_")
        self.domain = domain if domain is not None else 150 + os.getpid() % 80
        with open(os.path.join(SOURCE_DIR, "configs", "cyclonedds", "loopback.xml")) as f:
            xml = f.read()
        if "<Discovery>" not in xml:
            raise RuntimeError("loopback.xml has no <Discovery> to tag")
        self.xml_text = xml.replace(
            "<Discovery>", f"<Discovery><Tag>physclient-python-{os.getpid()}</Tag>", 1)
        self.xml = os.path.join(self.dir, "cyclone.xml")
        with open(self.xml, "w") as f:
            f.write(self.xml_text)
        self.toml = os.path.join(self.dir, "physd.toml")
        with open(self.toml, "w") as f:
            f.write(textwrap.dedent(f"""\
                [server]
                name = "{name}"
                log_level = "warn"
                status_period_s = 0.2
                {server_toml}
                [dds]
                domain = {self.domain}
                config = "{self.xml}"
                [paths]
                presets = "{SOURCE_DIR}/configs/presets.json"
                scenes = "{SOURCE_DIR}/configs/scenes"
                snapshots = "{self.dir}/snapshots"
                data = "{self.dir}/data"
                {extra_toml}
                """))
        if not os.access(PHYSD, os.X_OK):
            raise RuntimeError(f"no physd binary at {PHYSD} (set PHYSD_BINARY)")
        self.start()

    def start(self):
        self.proc = subprocess.Popen([PHYSD, "--config", self.toml])

    def kill(self):
        """SIGKILL: no chance to save anything; what survives is what the journal holds."""
        self.proc.kill()
        self.proc.wait()

    def client(self, **kw):
        kw.setdefault("connect_timeout", 30.0)
        kw.setdefault("request_timeout", 20.0)
        return pc.Client(domain=self.domain, cyclone_xml=self.xml_text, **kw)

    def stop(self):
        """SIGTERM; the daemon's exit status (None if it had to be killed)."""
        rc = self.proc.poll()
        if rc is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                rc = self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                rc = None
        shutil.rmtree(self.dir, ignore_errors=True)
        return rc


DAEMON = None


def setUpModule():
    global DAEMON
    DAEMON = Daemon(SERVER_NAME)


def tearDownModule():
    rc = DAEMON.stop()
    if rc != 0:
        raise AssertionError(f"physd did not exit cleanly on SIGTERM: {rc}")


def ground():
    return pc.BodyDef(type=pc.BodyType.Static,
                      shapes=[pc.ShapeDef(pc.ShapeGeom.plane((0, 0, 1), 0))])


def box(z, x=0.0, **kw):
    """A one-metre cube (1000 kg: density 1000) at (x, 0, z)."""
    return pc.BodyDef(position=(x, 0, z), shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.5, 0.5, 0.5)))],
                      **kw)


def f32(x):
    """x as the float32 the engine holds (so that == compares what the wire carries)."""
    import struct
    return struct.unpack("f", struct.pack("f", x))[0]


def wait_until(predicate, timeout=15.0, period=0.02):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(period)
    return predicate()


class Bindings(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.client = DAEMON.client(name="physclient-python-test")
        cls.server = cls.client.connect()

    @classmethod
    def tearDownClass(cls):
        cls.client.close()

    def new_world(self, what, **kw):
        w = self.client.create_world(f"{what}-{os.getpid()}", **kw)
        self.addCleanup(self._destroy, w)
        return w

    @staticmethod
    def _destroy(w):
        try:
            w.destroy()
        except (pc.Error, RuntimeError):
            pass

    def assertStatesEqual(self, a, b):
        self.assertEqual(a.tick, b.tick)
        self.assertEqual(a.ids, b.ids)
        for x, y in zip(a.bodies, b.bodies):
            self.assertEqual(x.position, y.position)
            self.assertEqual(x.rotation, y.rotation)
            self.assertEqual(x.linear_velocity, y.linear_velocity)
            self.assertEqual(x.angular_velocity, y.angular_velocity)

    # -- connection --------------------------------------------------------------------------

    def test_connect_gives_the_server(self):
        self.assertEqual(self.server.name, SERVER_NAME)
        self.assertGreater(self.server.protocol_version, 0)
        self.assertTrue(self.server.version)
        self.assertTrue(self.client.connected)
        self.assertNotEqual(self.client.client_id, 0)
        self.assertEqual(self.client.server.name, SERVER_NAME)
        self.assertEqual(self.client.domain, DAEMON.domain)
        w = self.new_world("named")
        self.assertEqual(self.client.world_named(f"named-{os.getpid()}"), w)
        self.assertIn(w.id, [s.world for s in self.client.list_worlds()])
        # phys/status comes every 0.2 s (the daemon's config).
        status = wait_until(self.client.latest_status, timeout=10)
        self.assertIsNotNone(status)
        self.assertEqual(status.server_name, SERVER_NAME)

    def test_a_key_file_keeps_the_proven_id_across_clients(self):
        # The default client proves a fresh id; a key file gives the same proven id each time,
        # so a second run of a script owns the worlds of the first.
        self.assertTrue(self.server.client_proven)
        with tempfile.TemporaryDirectory() as d:
            key = os.path.join(d, "me.key")
            with DAEMON.client(key_file=key) as first:
                self.assertTrue(first.connect().client_proven)
                w = first.create_world(f"keyed-{os.getpid()}", ephemeral=True)
                world_id, first_id = w.id, first.client_id
            self.assertEqual(os.stat(key).st_mode & 0o777, 0o600)
            with DAEMON.client(key_file=key) as second:
                self.assertTrue(second.connect().client_proven)
                self.assertEqual(second.client_id, first_id)
                self.assertEqual(second.world(world_id).step(2).tick, 2)
                second.world(world_id).destroy()

    # -- physics -----------------------------------------------------------------------------

    def test_free_fall_before_landing(self):
        w = self.new_world("fall", time_step=DT, sleep=False)
        z0 = 10.0
        ids = w.spawn([ground(), box(z0)])
        self.assertEqual(len(ids), 2)
        n = 30
        ack = w.step(n)
        self.assertEqual(ack.tick, n)
        self.assertEqual(ack.world, w.id)
        f = w.query_state([ids[1]])
        self.assertEqual(f.tick, n)
        t = f.time
        self.assertAlmostEqual(t, n * DT, places=6)
        b = f.bodies[0]
        self.assertEqual(b.id, ids[1])
        x, y, z = b.position
        # z0 - g t^2 / 2, within what a first-order integrator of step DT may differ by.
        self.assertLess(abs(z - (z0 - G * t * t / 2)), G * DT * t / 2 + 1e-3, (z, t))
        self.assertLess(z, z0 - 1.0)
        self.assertGreater(z, 0.5)  # not landed yet
        self.assertAlmostEqual(b.linear_velocity[2], -G * t, delta=2e-3)
        self.assertLess(abs(x) + abs(y), 1e-6)
        self.assertAlmostEqual(b.rotation[3], 1.0, places=6)  # (x, y, z, w)
        info = w.info()
        self.assertEqual((info.bodies, info.tick), (2, n))

    def test_resting_box_stays_put(self):
        w = self.new_world("rest", time_step=DT)
        ids = w.spawn([ground(), box(0.5)])
        w.step(120)
        b = w.query_state([ids[1]]).bodies[0]
        x, y, z = b.position
        self.assertLess(abs(z - 0.5), 0.01, z)
        self.assertLess(abs(x) + abs(y), 1e-3)
        self.assertLess(math.hypot(*b.linear_velocity), 0.05)
        self.assertGreater(abs(b.rotation[3]), 0.9999)

    def test_forces_impulses_torques_and_joints(self):
        w = self.new_world("forces", time_step=DT, sleep=False)
        a, b = w.spawn([box(5.0), box(5.0, x=3.0)])
        # An impulse acts now: 1000 N s on 1000 kg.
        w.apply_impulse(a, (1000, 0, 0))
        sa = w.query_state([a]).bodies[0]
        self.assertAlmostEqual(sa.linear_velocity[0], 1.0, delta=1e-4)
        # A force acts during the next step: m g up holds b for that step while a falls.
        w.apply_force(b, (0, 0, 1000 * G))
        # A torque too: I = m (1 + 1) / 12 about z, so tau = I gives w_z = DT after the step.
        inertia = 1000 * 2 / 12
        w.apply_torque(a, (0, 0, inertia))
        w.step(1)
        sa, sb = w.query_state([a, b]).bodies
        self.assertAlmostEqual(sb.linear_velocity[2], 0.0, delta=1e-3)
        self.assertAlmostEqual(sb.position[2], 5.0, delta=1e-4)
        self.assertAlmostEqual(sa.linear_velocity[2], -G * DT, delta=1e-3)
        self.assertAlmostEqual(sa.angular_velocity[2], DT, delta=1e-4)
        self.assertAlmostEqual(sa.position[0], DT * 1.0, delta=1e-4)

        w.set_pose(a, (1, 2, 3))
        w.set_velocity(a, (0, 0, 0), (0, 0, 0))
        sa = w.query_state([a]).bodies[0]
        self.assertEqual(sa.position, (1.0, 2.0, 3.0))
        self.assertEqual(sa.linear_velocity, (0.0, 0.0, 0.0))

        # b hangs from the world by a ball joint at its centre: it stays; freed, it falls.
        w.set_pose(b, (3, 0, 5))
        w.set_velocity(b, (0, 0, 0))
        joints = w.add_joints(pc.JointDef(type=pc.JointType.Ball, body_a=0, body_b=b,
                                          anchor_a=(3, 0, 5), anchor_b=(0, 0, 0)))
        self.assertEqual(len(joints), 1)
        self.assertEqual(w.info().joints, 1)
        w.step(60)
        sb = w.query_state([b]).bodies[0]
        self.assertAlmostEqual(sb.position[2], 5.0, delta=0.05)
        self.assertAlmostEqual(sb.position[0], 3.0, delta=0.05)
        w.remove_joints(joints)
        self.assertEqual(w.info().joints, 0)
        w.step(30)
        self.assertLess(w.query_state([b]).bodies[0].position[2], 4.0)

        w.remove_bodies([a])
        self.assertEqual(w.info().bodies, 1)
        with self.assertRaises(pc.Error):
            w.set_pose(a, (0, 0, 1))  # a stale id

    def test_load_scene(self):
        w = self.new_world("scene")
        ids = w.load_scene("vertical_stack")  # a ground and 20 cubes in a column
        self.assertEqual(len(ids.bodies), 21)
        info = w.info()
        self.assertEqual(info.bodies, len(ids.bodies))
        f = w.query_state()
        self.assertEqual(f.total, len(ids.bodies))
        self.assertEqual(set(f.ids), set(ids.bodies))
        top = max(b.position[2] for b in f.bodies)
        self.assertAlmostEqual(top, 19.5, delta=0.05)
        w.step(30)
        top_after = max(b.position[2] for b in w.query_state().bodies)
        self.assertAlmostEqual(top_after, top, delta=0.02)  # the column stands
        with self.assertRaises(pc.Error):
            w.load_scene("no_such_scene")
        self.assertEqual(w.info().bodies, 21)

    # -- time control ------------------------------------------------------------------------

    def test_pause_stops_the_tick_and_run_advances_it(self):
        w = self.new_world("run")
        w.spawn([ground(), box(3.0)])
        w.run(60)
        self.assertTrue(wait_until(lambda: w.info().tick > 5), "run did not advance the tick")
        self.assertTrue(w.info().running)
        ack = w.pause()
        first = w.info()
        self.assertFalse(first.running)
        time.sleep(0.3)
        second = w.info()
        self.assertEqual(first.tick, second.tick)
        self.assertEqual(ack.tick, first.tick)
        w.run(60)
        self.assertTrue(wait_until(lambda: w.info().tick > second.tick + 5))
        w.pause()

    # -- subscriptions -----------------------------------------------------------------------

    def test_subscription_frames(self):
        w = self.new_world("sub", sleep=False)
        ids = w.spawn([ground(), box(20.0)])
        frames = []
        enough = threading.Event()

        def on_frame(f):
            frames.append((f.tick, f.find(ids[1]).position[2], len(f.bodies)))
            if len(frames) >= 10:
                enough.set()

        with w.subscribe(on_frame) as sub, w.subscribe() as poll:
            self.assertTrue(sub.active)
            self.assertEqual(sub.world, w.id)
            w.run(60)
            self.assertTrue(enough.wait(30), f"{len(frames)} frames")
            f1 = poll.wait_for_frame(0, timeout=10)
            self.assertIsNotNone(f1)
            f2 = poll.wait_for_frame(f1.tick, timeout=10)
            self.assertIsNotNone(f2)
            self.assertGreater(f2.tick, f1.tick)
            latest = poll.latest()
            self.assertGreaterEqual(latest.tick, f2.tick)
            w.pause()
            self.assertGreaterEqual(sub.frames_received, 10)
        self.assertFalse(sub.active)
        got = frames[:10]
        ticks = [t for t, _, _ in got]
        self.assertEqual(ticks, sorted(set(ticks)), "ticks not increasing")
        zs = [z for _, z, _ in got]
        self.assertTrue(all(b < a for a, b in zip(zs, zs[1:])), f"the box did not fall: {zs}")
        self.assertTrue(all(n == 2 for _, _, n in got))
        # The buffer view: (n, 13) float32 rows in the order of bodies.
        view = memoryview(f2.array())
        self.assertEqual((view.format, view.shape), ("f", (2, 13)))
        rows = view.tolist()
        for row, body in zip(rows, f2.bodies):
            self.assertEqual(tuple(row[0:3]), body.position)
            self.assertEqual(tuple(row[3:7]), body.rotation)
            self.assertEqual(tuple(row[7:10]), body.linear_velocity)

    def test_subscriptions_through_pause_edits_restore_and_reset(self):
        # Issue 40: a new subscriber to a paused world got nothing, a paused world's edits
        # reached no subscriber, and a restore to an earlier tick or a reset froze every
        # subscription until the world passed its old tick again. Bounds: 2 s each.
        w = self.new_world("epochs")
        ids = w.spawn([ground(), box(5.0)])
        w.step(5)
        snap = w.save_snapshot()
        w.step(72)
        with w.subscribe() as sub:
            f = sub.wait_for_frame(0, timeout=2)  # paused: the whole state, no step needed
            self.assertIsNotNone(f, "no frame for a new subscriber to a paused world")
            self.assertEqual((f.tick, len(f.bodies), f.keyframe), (77, 2, True))
            self.assertGreaterEqual(f.epoch, 1)
            w.set_pose(ids[1], (1.0, 2.0, 3.0))
            self.assertTrue(
                wait_until(lambda: sub.latest().find(ids[1]).position == (1.0, 2.0, 3.0), 2),
                "a pose set in a paused world did not reach its subscriber")
            e = sub.latest()
            self.assertEqual((e.tick, e.epoch), (77, f.epoch))
            self.assertGreaterEqual(e.edit, 1)
            w.restore_snapshot(snap)
            g = sub.wait_for_frame(e.tick, timeout=2)
            self.assertIsNotNone(g, "the subscription froze after a restore to an earlier tick")
            self.assertEqual((g.tick, len(g.bodies)), (5, 2))
            self.assertGreater(g.epoch, e.epoch)
            self.assertStatesEqual(g, w.query_state())
            w.reset()
            h = sub.wait_for_frame(g.tick, timeout=2)
            self.assertIsNotNone(h, "the subscription froze after a reset")
            self.assertEqual((h.tick, len(h.bodies)), (0, 0))
            self.assertGreater(h.epoch, g.epoch)
        # query_state's frames are stamped by the server's clock too, and name the epoch.
        before = time.time_ns()
        q = w.query_state()
        self.assertLessEqual(abs(q.stamp_ns - before), 30 * 10**9)
        self.assertEqual(q.epoch, h.epoch)

    def test_callback_errors_and_requests_from_a_callback(self):
        w = self.new_world("cb", sleep=False)
        w.spawn([ground(), box(20.0)])
        reported = []
        old_hook = sys.unraisablehook
        sys.unraisablehook = lambda u: reported.append(u.exc_type)
        self.addCleanup(setattr, sys, "unraisablehook", old_hook)
        calls = []
        request_error = []

        def on_frame(f):
            calls.append(f.tick)
            if len(calls) == 1:
                try:
                    w.info()  # would wait for a reply only this thread can take
                except RuntimeError as e:
                    request_error.append(str(e))
            raise ValueError("a broken callback")

        with w.subscribe(on_frame) as sub:
            w.run(60)
            self.assertTrue(wait_until(lambda: len(calls) >= 5, timeout=30), calls)
            w.pause()
        # The SDK keeps delivering after a callback raised; each raise is reported. (A closed
        # subscription keeps its counts.)
        self.assertFalse(sub.active)
        self.assertGreaterEqual(sub.frames_received, 5)
        self.assertIn(ValueError, reported)
        self.assertEqual(len(request_error), 1, request_error)
        self.assertIn("callback", request_error[0])

    # -- snapshots ---------------------------------------------------------------------------

    def test_snapshot_save_and_restore(self):
        w = self.new_world("snap", time_step=DT, sleep=False)
        w.spawn([ground(), box(5.0),
                 box(8.0, x=2.0, angular_velocity=(0.3, 0.2, 0.1))])
        w.step(10)
        snap = w.save_snapshot()
        self.assertIsInstance(snap, bytes)
        self.assertGreater(len(snap), 0)
        saved = w.query_state()
        w.step(20)
        later = w.query_state()
        self.assertEqual(later.tick, 30)
        self.assertNotEqual(later.bodies[1].position, saved.bodies[1].position)

        ack = w.restore_snapshot(snap)
        self.assertEqual(ack.world, w.id)
        self.assertStatesEqual(w.query_state(), saved)
        # The engine's exact state: the same steps give the same states, bit for bit.
        w.step(20)
        self.assertStatesEqual(w.query_state(), later)
        # Any buffer will do.
        w.restore_snapshot(bytearray(snap))
        self.assertStatesEqual(w.query_state(), saved)
        # Strided ones too, copied in their order: a view of the reversed bytes backwards (its
        # pointer is at its first element, the reversed copy's last byte: read from there
        # straight on, it runs past the end) and every other byte of an interleaved copy.
        w.step(5)
        w.restore_snapshot(memoryview(snap[::-1])[::-1])
        self.assertStatesEqual(w.query_state(), saved)
        interleaved = bytearray(2 * len(snap))
        interleaved[::2] = snap
        w.step(5)
        w.restore_snapshot(memoryview(interleaved)[::2])
        self.assertStatesEqual(w.query_state(), saved)
        # A snapshot that is not one is refused, and the world stays as it was.
        with self.assertRaises(pc.Error):
            w.restore_snapshot(b"not a snapshot")
        self.assertStatesEqual(w.query_state(), saved)

    # -- world settings and definitions ------------------------------------------------------

    def test_world_settings(self):
        w = self.new_world("settings")
        ack = w.set_world(gravity=(0, 0, -1.62), time_step=1 / 120, sleep_time=1.5,
                          max_linear_speed=300.0, guard_retries=1)
        self.assertEqual(ack.world, w.id)
        s = w.settings()
        self.assertAlmostEqual(s.gravity[2], -1.62, places=6)
        self.assertAlmostEqual(s.time_step, 1 / 120, places=7)
        self.assertEqual((s.sleep_time, s.max_linear_speed, s.guard_retries), (1.5, 300.0, 1))
        self.assertTrue(s.sleep)
        self.assertTrue(s.preset)
        self.assertGreater(s.solver["iterations"], 0)
        # The solver's settings are set_solver's keywords.
        w.set_solver(**s.solver)
        # A value left out (or None) keeps the world's.
        w.set_world(sleep=False, gravity=None)
        s = w.settings()
        self.assertFalse(s.sleep)
        self.assertAlmostEqual(s.gravity[2], -1.62, places=6)
        w.set_gravity((0, 0, -9.81))
        self.assertAlmostEqual(w.settings().gravity[2], -9.81, places=5)
        # Refused values change nothing; mistakes are TypeErrors that say where to go.
        for bad in ({"gravity": (0, 0, math.nan)}, {"time_step": 0.0}, {"guard_retries": 99},
                    {"aabb_margin": -1.0}):
            with self.assertRaises(pc.InvalidArgument):
                w.set_world(**bad)
        with self.assertRaises(pc.InvalidArgument):
            w.set_world()
        self.assertAlmostEqual(w.settings().gravity[2], -9.81, places=5)
        with self.assertRaises(TypeError) as cm:
            w.set_solver(gravity=(0, 0, -1))
        self.assertIn("set_world", str(cm.exception))
        with self.assertRaises(TypeError):
            w.set_world(iterations=3)
        # Another client reads the settings but may not change them.
        with DAEMON.client(name="settings-other") as other:
            other.connect()
            ow = other.world(w.id)
            self.assertAlmostEqual(ow.settings().gravity[2], -9.81, places=5)
            with self.assertRaises(pc.PermissionDenied):
                ow.set_gravity((0, 0, -1))

    def test_a_gravity_change_wakes_a_sleeping_pile(self):
        w = self.new_world("wake")
        ids = w.spawn([ground()] + [box(0.5 + i) for i in range(3)])
        for _ in range(20):
            if w.info().sleeping_bodies == 3:
                break
            w.step(30)
        self.assertEqual(w.info().sleeping_bodies, 3)
        x0 = w.query_state(ids[3]).bodies[0].position[0]
        w.set_gravity((G, 0, -G))
        self.assertEqual(w.info().sleeping_bodies, 0)
        w.step(60)
        self.assertGreater(w.query_state(ids[3]).bodies[0].position[0], x0 + 0.2)

    def test_definitions_read_back(self):
        w = self.new_world("defs")
        crate = pc.BodyDef(position=(0, 0, 3), name="crate", linear_damping=0.3,
                           angular_damping=0.6, gravity_scale=0.5, mass=7.0,
                           inertia=(1.0, 2.0, 3.0), gyroscopic=False, allow_sleep=False,
                           shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.5, 0.25, 0.4)),
                                               material=pc.Material(friction=0.2,
                                                                    restitution=0.4,
                                                                    density=700))])
        ball = pc.BodyDef(position=(2, 0, 3), name="ball", gravity_scale=-0.25,
                          shapes=[pc.ShapeDef(pc.ShapeGeom.sphere(0.3),
                                              material=pc.Material(density=1500))])
        g = ground()
        g.name = "ground"
        ids = w.spawn([g, crate, ball])
        joints = w.add_joints(pc.JointDef(type=pc.JointType.Hinge, body_a=ids[1], body_b=ids[2],
                                          anchor_a=(1, 0, 0), anchor_b=(-1, 0, 0),
                                          axis_a=(0, 1, 0), axis_b=(0, 1, 0), name="hinge",
                                          enable_motor=True, max_motor_force=20.0))

        def check(world, when):
            bodies = world.all_bodies()
            self.assertEqual([b.definition.name for b in bodies], ["ground", "crate", "ball"],
                             when)
            c = bodies[1].definition
            self.assertEqual((c.linear_damping, c.angular_damping, c.gravity_scale, c.mass),
                             (f32(0.3), f32(0.6), 0.5, 7.0), when)
            self.assertEqual(c.inertia, (1.0, 2.0, 3.0), when)
            self.assertFalse(c.gyroscopic or c.allow_sleep, when)
            self.assertAlmostEqual(c.shapes[0].material.restitution, 0.4, places=6)
            self.assertEqual(c.shapes[0].geom.half_extents, (0.5, 0.25, f32(0.4)))
            self.assertEqual(bodies[1].mass, 7.0)
            self.assertEqual(bodies[2].definition.gravity_scale, -0.25)
            self.assertAlmostEqual(bodies[2].mass, 1500 * 4 / 3 * math.pi * 0.027, places=2)
            self.assertEqual(bodies[0].definition.type, pc.BodyType.Static)
            js = world.all_joints()
            self.assertEqual(len(js), 1)
            self.assertEqual(js[0].definition.name, "hinge")
            self.assertEqual(js[0].definition.type, pc.JointType.Hinge)
            self.assertEqual(js[0].definition.max_motor_force, 20.0)
            self.assertEqual((js[0].definition.body_a, js[0].definition.body_b),
                             (bodies[1].id, bodies[2].id))

        check(w, "as spawned")
        page = w.get_bodies(first=1, max_count=1)
        self.assertEqual((page.total, len(page)), (3, 1))
        self.assertEqual(page.bodies[0].definition.name, "crate")
        self.assertEqual(w.get_bodies([ids[2], ids[0]]).bodies[1].definition.name, "ground")
        self.assertEqual(w.get_joints(joints).joints[0].id, joints[0])
        with self.assertRaises(pc.NotFound):
            w.get_bodies(0x99900000001)
        # An engine snapshot restored into another world: every field.
        snap = w.save_snapshot()
        w2 = self.new_world("defs-restored")
        w2.restore_snapshot(snap)
        check(w2, "after an engine snapshot restore")

    # -- errors ------------------------------------------------------------------------------

    def test_errors_are_typed_and_change_nothing(self):
        self.assertTrue(issubclass(pc.InvalidArgument, pc.Error))
        self.assertTrue(issubclass(pc.NotFound, pc.Error))
        self.assertTrue(issubclass(pc.ResourceExhausted, pc.Error))
        self.assertTrue(issubclass(pc.Timeout, pc.Error) and issubclass(pc.Timeout, TimeoutError))
        self.assertTrue(issubclass(pc.Disconnected, ConnectionError))

        # An unknown world.
        with self.assertRaises(pc.Error) as cm:
            self.client.world(987654).step(1)
        e = cm.exception
        self.assertIn(e.code, (pc.ErrorCode.NotFound, pc.ErrorCode.InvalidArgument))
        self.assertIsInstance(e, getattr(pc, e.code.name))
        self.assertTrue(e.from_server)
        self.assertTrue(e.message)
        self.assertTrue(str(e).startswith(e.code.name + ": "), str(e))
        with self.assertRaises(pc.NotFound) as cm:
            self.client.world_named("no such world")
        self.assertEqual(cm.exception.code, pc.ErrorCode.NotFound)

        # A NaN position: refused, the world unchanged.
        w = self.new_world("errors", sleep=False)
        ids = w.spawn([ground(), box(2.0)])
        w.step(5)
        before = w.query_state()
        with self.assertRaises(pc.Error) as cm:
            w.set_pose(ids[1], (math.nan, 0, 1))
        self.assertEqual(cm.exception.code, pc.ErrorCode.InvalidArgument)
        self.assertIsInstance(cm.exception, pc.InvalidArgument)
        with self.assertRaises(pc.InvalidArgument):
            w.spawn(box(math.nan))
        self.assertStatesEqual(w.query_state(), before)
        self.assertEqual(w.info().bodies, 2)

        # No daemon answers in time: another domain (participants of one process share a
        # domain id's configuration) with a discovery tag nobody has.
        with pc.Client(domain=DAEMON.domain + 1, cyclone_xml=DAEMON.xml_text.replace(
                "physclient-python-", "nobody-"), connect_timeout=0.3) as lonely:
            t0 = time.monotonic()
            with self.assertRaises(pc.Timeout) as cm:
                lonely.connect()
            self.assertEqual(cm.exception.code, pc.ErrorCode.Timeout)
            self.assertFalse(cm.exception.from_server)
            self.assertLess(time.monotonic() - t0, 10)

        # Mistakes the bindings catch themselves.
        with self.assertRaises(TypeError):
            pc.BodyDef(no_such_field=1)
        with self.assertRaises(TypeError):
            pc.BodyDef(position=(1, 2))
        with self.assertRaises(ValueError):
            pc.ShapeGeom.hull([(0, 0, 0), (1, 0, 0), (0, 1, 0)])  # three points
        with self.assertRaises(ValueError):
            pc.ShapeGeom.hull([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, math.nan)])
        with self.assertRaises(TypeError):
            w.set_solver(no_such_setting=1)
        with self.assertRaises(TypeError):
            w.spawn("a box")

    def test_timeouts(self):
        w = self.new_world("timeouts")
        # Longer than the SDK can add to its clock (1e10 s overflows its int64 nanoseconds; a
        # request would time out at once): the longest timeout (24 days) instead.
        self.assertEqual(w.step(1, timeout=1e10).tick, 1)
        self.assertEqual(w.step(1, timeout=1e300).tick, 2)
        self.assertEqual(w.step(1, timeout=math.inf).tick, 3)
        for bad in (-1.0, -math.inf, math.nan):
            with self.assertRaises(ValueError):
                w.step(1, timeout=bad)
            with self.assertRaises(ValueError):
                DAEMON.client(request_timeout=bad)
        self.assertEqual(w.info().tick, 3)
        with DAEMON.client(name="patient", connect_timeout=1e10, request_timeout=1e10) as c:
            c.connect()
            self.assertIn(w.id, [s.world for s in c.list_worlds()])
        with w.subscribe() as sub:
            with self.assertRaises(ValueError):
                sub.wait_for_frame(0, timeout=math.nan)
            w.run(60)
            self.assertIsNotNone(sub.wait_for_frame(0, timeout=1e10))
            w.pause()

    def test_a_synchronous_loop_is_never_refused(self):
        # Issue 40: step(1); query_state(); info() in a loop, one request at a time, faster than
        # the daemon's default 2,000 commands a second, is never answered "slow down" (without
        # the SDK's retry, so that a refusal would show).
        with DAEMON.client(name="loop", retry_busy=False) as c:
            c.connect()
            w = c.create_world(f"loop-{os.getpid()}", ephemeral=True)
            self.addCleanup(self._destroy, w)
            n, end = 0, time.monotonic() + 1.5
            while time.monotonic() < end:
                w.step(1)
                w.query_state()
                w.info()
                n += 3
            self.assertEqual(w.info().tick, n // 3)

    def test_definitions(self):
        b = pc.BodyDef(type=pc.BodyType.Kinematic, position=(1, 2, 3), rotation=(0, 0, 1, 0),
                       mass=2.5, name="k", shapes=[pc.ShapeDef(pc.ShapeGeom.sphere(0.25),
                                                               local_position=(0, 0, 1),
                                                               material=pc.Material(friction=0.1))])
        self.assertEqual(b.type, pc.BodyType.Kinematic)
        self.assertEqual(b.position, (1.0, 2.0, 3.0))
        self.assertEqual(b.rotation, (0.0, 0.0, 1.0, 0.0))
        self.assertEqual((b.mass, b.name), (2.5, "k"))
        s = b.shapes[0]
        self.assertEqual(s.geom.type, pc.ShapeType.Sphere)
        self.assertEqual(s.geom.radius, 0.25)
        self.assertEqual(s.local_position, (0.0, 0.0, 1.0))
        self.assertAlmostEqual(s.material.friction, 0.1, places=6)
        # A hull is its points until a world builds it: the cube's corners and its centre.
        corners = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
        hull = pc.ShapeGeom.hull(corners + [(0.5, 0.5, 0.5)])
        self.assertEqual(hull.type, pc.ShapeType.Hull)
        self.assertEqual(len(hull.hull_vertices), 9)
        capsule = pc.ShapeGeom.capsule(0.2, 0.5)
        self.assertEqual((capsule.type, capsule.half_height), (pc.ShapeType.Capsule, 0.5))
        j = pc.JointDef(type=pc.JointType.Hinge, body_a=(7 << 32) | 3, enable_motor=True)
        self.assertEqual((j.body_a, j.body_b, j.enable_motor), ((7 << 32) | 3, 0, True))
        # A hull body and a capsule spawn and fall like any other.
        w = self.new_world("shapes", sleep=False)
        ids = w.spawn([pc.BodyDef(position=(0, 0, 5), shapes=[pc.ShapeDef(hull)]),
                       pc.BodyDef(position=(3, 0, 5), shapes=[pc.ShapeDef(capsule)])])
        w.step(10)
        for body in w.query_state(ids).bodies:
            self.assertLess(body.position[2], 5.0 - 0.1)
        # The daemon built the hull: the centre is inside, so the world's hull has the corners.
        built = w.get_bodies([ids[0]]).bodies[0].definition.shapes[0].geom.hull_vertices
        self.assertEqual(sorted(built), sorted(tuple(map(float, c)) for c in corners))
        # Points that span no volume: the daemon refuses the spawn and names the shape.
        flat = pc.ShapeGeom.hull([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)])
        with self.assertRaises(pc.InvalidArgument) as cm:
            w.spawn(pc.BodyDef(shapes=[pc.ShapeDef(flat)]))
        self.assertIn("shapes[0].convex_hull.points do not make a hull", cm.exception.message)
        self.assertEqual(len(w.all_bodies()), 2)

    def test_requests_from_threads(self):
        # Requests release the GIL while they wait. Another thread keeps running while a long
        # step() is in flight: a ticker (a short sleep, then a timestamp, which needs the GIL)
        # stamps all through the step. Were the GIL held, it could not stamp from just after the
        # call to just before its end.
        w = self.new_world("long-step", sleep=False)
        w.spawn([ground()] + [box(0.5 + 1.2 * k, x=1.2 * i) for i in range(20) for k in range(10)])
        stamps = []
        stop = threading.Event()

        def ticker():
            while not stop.is_set():
                time.sleep(0.002)
                stamps.append(time.monotonic())

        t = threading.Thread(target=ticker)
        t.start()
        try:
            t0 = time.monotonic()
            ack = w.step(600)
            t1 = time.monotonic()
        finally:
            stop.set()
            t.join(10)
        self.assertEqual(ack.tick, 600)
        self.assertGreater(t1 - t0, 0.1, "the step is too short to show anything")
        inside = [s for s in stamps if t0 + 0.03 < s < t1 - 0.03]
        self.assertGreaterEqual(len(inside), 10, (t1 - t0, len(stamps)))

        # Threads step worlds of their own at once.
        worlds = [self.new_world(f"thread{i}", sleep=False) for i in range(4)]
        errors = []

        def work(w):
            try:
                (body,) = w.spawn(box(50.0))
                for _ in range(20):
                    w.step(1)
                f = w.query_state([body])
                if f.tick != 20 or not f.bodies[0].position[2] < 50.0:
                    errors.append((w.id, f.tick, f.bodies[0].position))
            except Exception as e:  # noqa: BLE001 (reported below)
                errors.append(e)

        threads = [threading.Thread(target=work, args=(w,)) for w in worlds]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        self.assertFalse(any(t.is_alive() for t in threads))
        self.assertEqual(errors, [])

    # -- lifetime ----------------------------------------------------------------------------

    def test_close_waits_for_a_running_callback(self):
        # A slow callback (it lets go of the GIL) is running when close() is called on this
        # thread: close() returns only once it has finished, and none starts after.
        w = self.new_world("close-waits", sleep=False)
        w.spawn(box(10.0))
        inside, done, calls_after = threading.Event(), threading.Event(), []
        closed = [False]

        def on_frame(f):
            if closed[0]:
                calls_after.append(f.tick)
            done.clear()
            inside.set()
            time.sleep(0.05)
            done.set()

        sub = w.subscribe(on_frame)
        w.run(60)
        self.assertTrue(inside.wait(10))
        inside.clear()
        self.assertTrue(inside.wait(10))  # the next call, under way
        sub.close()
        closed[0] = True
        self.assertTrue(done.is_set(), "close() returned while the callback ran")
        time.sleep(0.3)
        self.assertEqual(calls_after, [])
        w.pause()

    def test_close_from_a_callback(self):
        # A client closed by its own callback (on the SDK's thread, which closing joins).
        c = DAEMON.client(name="self-closer")
        c.connect()
        w = c.create_world(f"self-closer-{os.getpid()}", ephemeral=True)
        w.spawn(box(10.0))
        closed = threading.Event()

        def on_frame(f):
            if not closed.is_set():
                c.close()
                closed.set()

        sub = w.subscribe(on_frame)
        w.run(60)
        self.assertTrue(closed.wait(30))
        self.assertTrue(wait_until(lambda: c.closed, timeout=5))
        with self.assertRaises(RuntimeError):
            w.info()
        sub.close()
        try:
            self._destroy(self.client.world_named(f"self-closer-{os.getpid()}"))
        except pc.NotFound:
            pass

    def test_close_while_other_threads_use_the_subscription(self):
        # close() while other threads wait in wait_for_frame() or read latest() and the counts
        # with the GIL released: the subscription's state (the condition variable a waiter
        # blocks on) lives until they are done with it.
        w = self.new_world("close-race", sleep=False)
        w.spawn([ground(), box(20.0)])
        w.run(60)
        errors = []
        for _ in range(8):
            calls = []
            sub = w.subscribe(lambda f: calls.append(f.tick))
            self.assertIsNotNone(sub.wait_for_frame(0, timeout=20))
            stop = threading.Event()

            def use(sub=sub, stop=stop):
                try:
                    while not stop.is_set():
                        sub.wait_for_frame(1 << 62, timeout=0.05)  # no such tick: waits
                        sub.latest()
                        sub.frames_received
                        sub.frames_skipped
                except Exception as e:  # noqa: BLE001 (reported below)
                    errors.append(e)

            threads = [threading.Thread(target=use) for _ in range(3)]
            for t in threads:
                t.start()
            time.sleep(0.05)
            sub.close()
            self.assertFalse(sub.active)
            stop.set()
            for t in threads:
                t.join(10)
            self.assertFalse(any(t.is_alive() for t in threads))
            # Closed: no more calls, no frames, the counts kept; no waiting for what cannot come.
            n = len(calls)
            t0 = time.monotonic()
            self.assertIsNone(sub.wait_for_frame(0, timeout=5))
            self.assertLess(time.monotonic() - t0, 1.0)
            self.assertIsNone(sub.latest())
            self.assertGreaterEqual(sub.frames_received, 1)
            time.sleep(0.05)
            self.assertEqual(len(calls), n)
        w.pause()
        self.assertEqual(errors, [])

    def test_on_event_replaced_while_others_read(self):
        # on_event() replaces the SDK's function under a lock that latest_status(), recent_events()
        # and server take with the GIL held; the old callback must not be released there (it
        # would wait for the GIL: both threads stuck).
        c = DAEMON.client(name="events")
        c.connect()
        self.addCleanup(c.close)
        stop = threading.Event()
        errors = []

        def read():
            try:
                while not stop.is_set():
                    c.latest_status()
                    c.recent_events()
                    c.server
            except Exception as e:  # noqa: BLE001 (reported below)
                errors.append(e)

        def replace():
            try:
                for i in range(3000):  # before the fix, some runs got stuck in this loop
                    c.on_event(lambda e, i=i: None)
                c.on_event(None)
            except Exception as e:  # noqa: BLE001 (reported below)
                errors.append(e)
            finally:
                stop.set()

        threads = [threading.Thread(target=read, daemon=True) for _ in range(2)]
        threads.append(threading.Thread(target=replace, daemon=True))
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        self.assertFalse(any(t.is_alive() for t in threads), "stuck")
        self.assertEqual(errors, [])
        # A callback left when the client closes is let go (it may refer to the client).
        class Callback:
            def __call__(self, event):
                pass

        cb = Callback()
        cb.client = c
        ref = weakref.ref(cb)
        c.on_event(cb)
        del cb
        self.assertIsNotNone(ref())
        c.close()
        self.assertIsNone(ref())
        with self.assertRaises(RuntimeError):
            c.on_event(None)

    def test_close_and_exit(self):
        c = DAEMON.client(name="closer")
        c.connect()
        w = c.create_world(f"closer-{os.getpid()}", ephemeral=True)
        self.assertEqual(w.step(2).tick, 2)
        c.close()
        self.assertTrue(c.closed)
        with self.assertRaises(RuntimeError):
            w.step(1)
        # A script that exits with a client, a running world and a subscription callback still
        # open exits cleanly (the atexit hook closes the client before Python finalizes).
        script = textwrap.dedent(f"""\
            import time, physclient as pc
            c = pc.Client(domain={DAEMON.domain}, cyclone_xml=open({DAEMON.xml!r}).read(),
                          connect_timeout=30)
            c.connect()
            w = c.create_world("exiting-{os.getpid()}", ephemeral=True)
            w.spawn(pc.BodyDef(position=(0, 0, 1),
                               shapes=[pc.ShapeDef(pc.ShapeGeom.sphere(0.5))]))
            seen = []
            sub = w.subscribe(lambda f: seen.append(f.tick))
            w.run(60)
            deadline = time.time() + 20
            while len(seen) < 3 and time.time() < deadline:
                time.sleep(0.01)
            print("frames", len(seen))
            """)
        r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                           timeout=60)
        self.assertEqual(r.returncode, 0, r.stderr)
        n = int(re.search(r"frames (\d+)", r.stdout).group(1))
        self.assertGreaterEqual(n, 3)
        try:
            self._destroy(self.client.world_named(f"exiting-{os.getpid()}"))
        except pc.NotFound:
            pass


def every_kind():
    """Bodies of every kind and shapes of every type, a value other than the default in every
    field, and one joint of every type: (bodies, joints as (def, index a, index b); -1: world)."""
    g = ground()
    g.name = "ground"
    g.shapes[0].material = pc.Material(friction=0.8, restitution=0.1)
    crate = pc.BodyDef(position=(0, 0, 2), name="crate", linear_damping=0.3, angular_damping=0.6,
                       gravity_scale=0.5, mass=7.0, inertia=(1.0, 2.0, 3.0), gyroscopic=False,
                       allow_sleep=False,
                       shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.5, 0.25, 0.4)),
                                           material=pc.Material(friction=0.2, restitution=0.4,
                                                                density=700)),
                               pc.ShapeDef(pc.ShapeGeom.capsule(0.1, 0.3),
                                           local_position=(0, 0, 0.6))])
    ball = pc.BodyDef(position=(2, 0, 2), name="ball", gravity_scale=-0.25,
                      shapes=[pc.ShapeDef(pc.ShapeGeom.sphere(0.3),
                                          material=pc.Material(density=1500))])
    hull = pc.BodyDef(position=(-2, 0, 2), name="hull",
                      shapes=[pc.ShapeDef(pc.ShapeGeom.hull(
                          [(-0.3, -0.3, -0.3), (0.3, -0.3, -0.3), (0, 0.3, -0.3), (0, 0, 0.4)]))])
    platform = pc.BodyDef(type=pc.BodyType.Kinematic, position=(0, 3, 1), name="platform",
                          linear_velocity=(0.5, 0, 0), angular_velocity=(0, 0, 0.25),
                          shapes=[pc.ShapeDef(pc.ShapeGeom.capsule(0.2, 0.5),
                                              local_position=(0.1, 0, 0),
                                              local_rotation=(0, 0.70710677, 0, 0.70710677),
                                              material=pc.Material(friction=0.9, restitution=0.2,
                                                                   density=300))])
    slide = pc.BodyDef(position=(3, -2, 0.5), name="slide", mass=2.0,
                       shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.2, 0.2, 0.2)))])
    J = pc.JointType
    joints = [
        (pc.JointDef(type=J.Hinge, anchor_a=(1, 0, 0), anchor_b=(-1, 0, 0), axis_a=(0, 1, 0),
                     axis_b=(0, 1, 0), enable_limit=True, lower=-0.5, upper=0.7,
                     enable_motor=True, motor_speed=0.5, max_motor_force=20.0, name="hinge"),
         1, 2),
        (pc.JointDef(type=J.Distance, anchor_a=(-2, 0, 4), length=2.0, spring_hertz=3.0,
                     spring_damping_ratio=0.5, collide_connected=True, name="rope"), -1, 3),
        (pc.JointDef(type=J.Ball, anchor_a=(0, 0.5, 0), anchor_b=(0, -0.5, 0.1),
                     name="ball joint"), 2, 3),
        (pc.JointDef(type=J.Fixed, anchor_a=(0.2, 0, 0), anchor_b=(-0.2, 0, 0),
                     collide_connected=True, name="weld"), 4, 1),
        (pc.JointDef(type=J.Prismatic, anchor_a=(3, -2, 0.5), axis_a=(1, 0, 0), axis_b=(1, 0, 0),
                     enable_limit=True, lower=-0.25, upper=0.75, enable_motor=True,
                     motor_speed=-0.1, max_motor_force=40.0, name="slider"), -1, 5),
    ]
    return [g, crate, ball, hull, platform, slide], joints


def as_f32(v):
    """Every float in a nested value as the float32 the engine holds."""
    if isinstance(v, float):
        return f32(v)
    if isinstance(v, (tuple, list)):
        return type(v)(as_f32(x) for x in v)
    if isinstance(v, dict):
        return {k: as_f32(x) for k, x in v.items()}
    return v


def body_fields(d):
    """Every field of a body definition but pose and velocities (state, which moves)."""
    return as_f32({
        "type": d.type, "name": d.name, "linear_damping": d.linear_damping,
        "angular_damping": d.angular_damping, "gravity_scale": d.gravity_scale, "mass": d.mass,
        "inertia": d.inertia, "gyroscopic": d.gyroscopic, "allow_sleep": d.allow_sleep,
        "shapes": [{"type": s.geom.type, "radius": s.geom.radius,
                    "half_extents": s.geom.half_extents, "half_height": s.geom.half_height,
                    "normal": s.geom.normal, "offset": s.geom.offset,
                    "hull_vertices": list(s.geom.hull_vertices),
                    "local_position": s.local_position, "local_rotation": s.local_rotation,
                    "material": (s.material.friction, s.material.restitution,
                                 s.material.density)} for s in d.shapes]})


def joint_fields(j):
    """Every field of a joint definition but its bodies."""
    return as_f32({k: getattr(j, k) for k in (
        "type", "name", "anchor_a", "anchor_b", "axis_a", "axis_b", "enable_limit", "lower",
        "upper", "enable_motor", "motor_speed", "max_motor_force", "length", "spring_hertz",
        "spring_damping_ratio", "collide_connected")})


class DurableDefinitions(unittest.TestCase):
    """What a world reports after its daemon was killed (SIGKILL) and restarted on its data
    folder, and after a snapshot of it was restored: every field of every body, shape and
    joint as it was given (a daemon of its own, on another domain)."""

    def test_every_kind_of_definition_survives_a_killed_daemon_and_a_snapshot(self):
        d = Daemon("physd-python-durable", domain=150 + (os.getpid() + 40) % 80)
        c = None
        try:
            c = d.client(name="physclient-python-durable")
            c.connect()
            w = c.create_world("kept")
            bodies, joints = every_kind()
            ids = w.spawn(bodies)
            for j, a, b in joints:
                j.body_a = ids[a] if a >= 0 else 0
                j.body_b = ids[b] if b >= 0 else 0
            w.add_joints([j for j, _, _ in joints])
            want_bodies = [body_fields(b) for b in bodies]
            want_joints = [(joint_fields(j), j.body_a, j.body_b) for j, _, _ in joints]

            def check(world, when):
                got = world.all_bodies()
                if world is w:
                    self.assertEqual([b.id for b in got], ids, when)
                self.assertEqual([body_fields(b.definition) for b in got], want_bodies, when)
                got_joints = world.all_joints()
                by_old = dict(zip(ids, [b.id for b in got]))
                by_old[0] = 0
                self.assertEqual([(joint_fields(j.definition), j.definition.body_a,
                                   j.definition.body_b) for j in got_joints],
                                 [(f, by_old[a], by_old[b]) for f, a, b in want_joints], when)

            check(w, "as spawned")
            w.step(5)
            snap = w.save_snapshot()
            d.kill()
            d.start()
            self.assertTrue(wait_until(lambda: c.reconnects >= 1, timeout=30),
                            "the client did not reconnect to the restarted daemon")
            check(w, "after a restart")
            w2 = c.create_world("restored")
            w2.restore_snapshot(snap)
            check(w2, "restored from a snapshot after a restart")
        finally:
            if c is not None:
                c.close()
            d.stop()


class Cluster(unittest.TestCase):
    """Three daemons of one domain (docs/SERVER.md "Several daemons"), one Python client."""

    @classmethod
    def setUpClass(cls):
        domain = 140 + (os.getpid() + 5) % 10
        cls.daemons = [Daemon(f"physd-cluster-{i}", domain=domain, server_toml=f"id = {i}",
                              extra_toml="[cluster]\nenabled = true")
                       for i in (1, 2, 3)]
        cls.client = cls.daemons[0].client(name="physclient-python-cluster")
        cls.client.connect()

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        for d in cls.daemons:
            if d.stop() != 0:
                raise AssertionError("a cluster daemon did not exit cleanly on SIGTERM")

    def test_worlds_are_placed_reached_and_answered_once(self):
        c = self.client
        self.assertTrue(wait_until(lambda: len(c.daemons()) == 3, timeout=20))
        self.assertTrue(all(d.cluster for d in c.daemons()))
        worlds = [c.create_world(f"py{i}") for i in range(30)]
        owners = [w.id >> 20 for w in worlds]
        self.assertEqual(sorted(owners.count(d) for d in (1, 2, 3)), [10, 10, 10])
        for w in worlds:
            (body,) = w.spawn([box(5.0)])
            self.assertEqual(w.step(30).tick, 30)
            self.assertLess(w.query_state([body]).bodies[0].position[2], 4.0)
        listed = c.list_worlds()
        self.assertEqual(len(listed), 30)
        for s in listed:
            self.assertEqual(s.daemon, s.world >> 20)
            self.assertEqual(s.bodies, 1)
        self.assertEqual(len(c.list_worlds(daemon=3)), 10)
        named = c.create_world("on-two", daemon=2)
        self.assertEqual(named.id >> 20, 2)
        with self.assertRaises(pc.NotFound):
            c.world((9 << 20) | 1).step(1)
        time.sleep(0.3)
        self.assertEqual(c.duplicate_replies(), 0)


class ExampleScript(unittest.TestCase):
    def test_drop_boxes(self):
        r = subprocess.run([sys.executable, EXAMPLE, "--domain", str(DAEMON.domain),
                            "--cyclone-xml", DAEMON.xml], capture_output=True, text=True,
                           timeout=90)
        self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
        self.assertIn(f"connected to {SERVER_NAME}", r.stdout)
        zs = sorted(float(z) for z in re.findall(r"^box \d+: x=\S+ y=\S+ z=(\S+)$", r.stdout,
                                                   re.M))
        self.assertEqual(len(zs), 3, r.stdout)
        # Dropped from 1, 2.5 and 4 m, the three cubes come to rest in a column.
        for i, z in enumerate(zs):
            self.assertAlmostEqual(z, 0.5 + i, delta=0.1, msg=r.stdout)
        # It destroyed its world.
        with DAEMON.client() as c:
            c.connect()
            self.assertFalse([s for s in c.list_worlds() if s.name.startswith("drop-boxes-")])


if __name__ == "__main__":
    unittest.main()
