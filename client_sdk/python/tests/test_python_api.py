#!/usr/bin/env python3
"""physclient as a Python user expects it (issue 40, point 6), against a physd of its own.

    FrameSequence  a StateFrame is a sequence of its bodies: len, frame[i], frame[a:b],
                   iteration, frame.get(id), `id in frame`; the buffer view unchanged
    WorldContext   `with client.create_world(...) as w:` destroys the world at the end of the
                   block (an exception too); a World that only names a world leaves it be
    EnumNames      enum arguments by name (BodyDef(type="static")); a wrong one raises one
                   sentence naming the valid values
    Asyncio        <request>_async: asyncio.Futures settled without blocking the loop, many in
                   flight, typed errors, frames by await and `async for`
    Timestamps     frames carry the server's time (stamp_ns, stamp)

The daemon is test_physclient.Daemon (a domain and a discovery tag of this process). ctest runs
this file as physclient_python_api (client_sdk/python/CMakeLists.txt).
"""
import asyncio
import math
import os
import sys
import threading
import time
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_physclient import Daemon, box, ground, wait_until  # noqa: E402

import physclient as pc  # noqa: E402

DAEMON = None


def setUpModule():
    global DAEMON
    DAEMON = Daemon("physd-python-api")


def tearDownModule():
    rc = DAEMON.stop()
    if rc != 0:
        raise AssertionError(f"physd did not exit cleanly on SIGTERM: {rc}")


class WithClient(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.client = DAEMON.client(name=f"python-api-{cls.__name__}")
        cls.client.connect()

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

    def world_names(self):
        return {s.name for s in self.client.list_worlds()}


class FrameSequence(WithClient):
    def test_a_frame_is_a_sequence_of_its_bodies(self):
        w = self.new_world("frames", sleep=False)
        ids = w.spawn([ground()] + [box(2.0 + 2 * i, x=0.1 * i) for i in range(5)])
        w.step(3)
        f = w.query_state()
        self.assertEqual(len(f), 6)
        self.assertEqual([b.id for b in f], ids)                 # iteration, in order
        self.assertEqual([b.id for b in f], [b.id for b in f.bodies])
        self.assertEqual(f[0].id, ids[0])
        self.assertEqual(f[-1].id, ids[-1])
        self.assertEqual(f[5].position, f.bodies[5].position)
        self.assertEqual([b.id for b in f[1:4]], ids[1:4])       # a slice: a list
        self.assertEqual([b.id for b in f[::-2]], ids[::-2])
        self.assertEqual([b.id for b in reversed(f)], ids[::-1])
        for bad in (6, -7, 1 << 40, ids[1]):                     # an id is not a position
            with self.assertRaises(IndexError) as cm:
                f[bad]
            self.assertIn("frame.get(id)", str(cm.exception))
        with self.assertRaises(TypeError):
            f["a"]
        # By id: get(id), `in`.
        for i in ids:
            self.assertEqual(f.get(i).id, i)
            self.assertIn(i, f)
        self.assertEqual(f.get(ids[3]).position, f.bodies[3].position)
        self.assertIsNone(f.get(ids[1] + (7 << 32)))             # another generation
        self.assertEqual(f.get(12345, "none"), "none")
        self.assertIsNone(f.get(-1))
        self.assertIsNone(f.get(1 << 70))
        with self.assertRaises(TypeError):
            f.get("a")
        self.assertNotIn(12345, f)
        self.assertNotIn(-1, f)
        self.assertIn(f[2], f)                                   # a BodyState: by its id
        # A query for given ids answers in their order (not the index order): get() finds
        # each body all the same.
        order = [ids[4], ids[1], ids[5], ids[2]]
        q = w.query_state(order)
        self.assertEqual([b.id for b in q], order)
        for i in order:
            self.assertEqual(q.get(i).id, i)
        self.assertIsNone(q.get(ids[3]))
        # Removed bodies leave holes in the index order: still found by id.
        w.remove_bodies([ids[2]])
        (new,) = w.spawn(box(30.0))                              # reuses index 2
        g = w.query_state()
        self.assertEqual(len(g), 6)
        self.assertIsNone(g.get(ids[2]))
        self.assertEqual(g.get(new).id, new)
        # The buffer view is what it was: (n, 13) float32 rows in the order of the bodies.
        view = memoryview(g.array())
        self.assertEqual((view.format, view.shape), ("f", (6, 13)))
        for row, body in zip(view.tolist(), g):
            self.assertEqual(tuple(row[0:3]), body.position)
            self.assertEqual(tuple(row[3:7]), body.rotation)

    def test_subscription_frames_are_sequences_too(self):
        w = self.new_world("sub-frames", sleep=False)
        ids = w.spawn([ground(), box(10.0)])
        seen = []
        done = threading.Event()

        def on_frame(f):
            seen.append((len(f), [b.id for b in f], f.get(ids[1]).position[2]))
            if len(seen) >= 3:
                done.set()

        with w.subscribe(on_frame):
            w.run(60)
            self.assertTrue(done.wait(30), seen)
            w.pause()
        for n, order, z in seen[:3]:
            self.assertEqual((n, order), (2, ids))
            self.assertLess(z, 10.0)


class WorldContext(WithClient):
    def test_the_end_of_the_block_destroys_a_created_world(self):
        name = f"ctx-{os.getpid()}"
        with self.client.create_world(name) as w:
            self.assertTrue(w.created)
            self.assertIn(name, self.world_names())
            w.spawn(box(1.0))
            self.assertEqual(w.step(2).tick, 2)
        self.assertNotIn(name, self.world_names())
        with self.assertRaises(pc.NotFound):
            w.step(1)

    def test_an_exception_in_the_block_destroys_it_and_goes_on(self):
        name = f"ctx-raise-{os.getpid()}"
        with self.assertRaises(KeyError):
            with self.client.create_world(name, ephemeral=True):
                raise KeyError("in the block")
        self.assertNotIn(name, self.world_names())

    def test_destroyed_inside_the_block_is_fine(self):
        name = f"ctx-gone-{os.getpid()}"
        with self.client.create_world(name) as w:
            w.destroy()
        self.assertNotIn(name, self.world_names())

    def test_a_world_only_named_is_left_as_it_is(self):
        w = self.new_world("ctx-named")
        for other in (self.client.world(w.id), self.client.world_named(f"ctx-named-{os.getpid()}")):
            self.assertFalse(other.created)
            self.assertEqual(other, w)
            with other as same:
                self.assertIs(same, other)
            self.assertEqual(w.info().world, w.id)  # still there

    def test_async_with(self):
        name = f"ctx-async-{os.getpid()}"

        async def main():
            async with await self.client.create_world_async(name, ephemeral=True) as w:
                self.assertTrue(w.created)
                self.assertIn(name, [s.name for s in await self.client.list_worlds_async()])
                await w.step_async(1)
            self.assertNotIn(name, [s.name for s in await self.client.list_worlds_async()])
            with self.assertRaises(ZeroDivisionError):    # not swallowed by __aexit__
                async with await self.client.create_world_async(name) as w:
                    1 / 0
            self.assertNotIn(name, [s.name for s in await self.client.list_worlds_async()])
            async with self.client.world(w.id):            # gone already: nothing to do
                pass

        asyncio.run(main())


class EnumNames(WithClient):
    def test_enum_arguments_by_name(self):
        self.assertEqual(pc.BodyDef(type="static").type, pc.BodyType.Static)
        self.assertEqual(pc.BodyDef(type="Kinematic").type, pc.BodyType.Kinematic)
        self.assertEqual(pc.BodyDef(type=pc.BodyType.Dynamic).type, pc.BodyType.Dynamic)
        self.assertEqual(pc.JointDef(type="hinge").type, pc.JointType.Hinge)
        b = pc.BodyDef()
        b.type = "STATIC"
        self.assertEqual(b.type, pc.BodyType.Static)
        # A point given in the world frame by name: the same push as PointFrame.World.
        w = self.new_world("enum-frame", sleep=False, gravity=(0, 0, 0))
        a, c = w.spawn([box(5.0), box(5.0, x=3.0)])
        w.apply_impulse(a, (0, 1000, 0), (0.5, 0, 5), frame="world")
        w.apply_impulse(c, (0, 1000, 0), (3.5, 0, 5), frame=pc.PointFrame.World)
        sa, sc = w.query_state([a, c])
        self.assertEqual(sa.angular_velocity, sc.angular_velocity)
        self.assertNotEqual(sa.angular_velocity, (0.0, 0.0, 0.0))

    def test_a_wrong_name_is_one_sentence_naming_the_values(self):
        with self.assertRaises(ValueError) as cm:
            pc.BodyDef(type="statik")
        msg = str(cm.exception)
        self.assertNotIn("\n", msg)
        self.assertLess(len(msg), 200, msg)
        for name in ("Static", "Kinematic", "Dynamic", "statik"):
            self.assertIn(name, msg)
        with self.assertRaises(TypeError) as cm:
            pc.BodyDef(type=3)
        msg = str(cm.exception)
        self.assertNotIn("\n", msg)
        self.assertIn("BodyType.Static", msg)
        with self.assertRaises(ValueError) as cm:
            pc.JointDef(type="weld")
        self.assertIn("JointType.Fixed", str(cm.exception))
        self.assertNotIn("\n", str(cm.exception))
        w = self.client.world(1)  # no request before the arguments are read
        with self.assertRaises(ValueError) as cm:
            w.apply_force(1, (0, 0, 1), frame="body")
        self.assertIn("PointFrame.Local", str(cm.exception))
        self.assertNotIn("\n", str(cm.exception))


class Asyncio(WithClient):
    def run_async(self, coro, timeout=120):
        return asyncio.run(asyncio.wait_for(coro, timeout))

    def test_requests_as_futures(self):
        w = self.new_world("aio", time_step=1 / 60, sleep=False)

        async def main():
            ids = await w.spawn_async([ground(), box(10.0)])
            self.assertEqual(len(ids), 2)
            fut = w.step_async(30)  # sent now; a Future of the Ack
            self.assertIsInstance(fut, asyncio.Future)
            ack = await fut
            self.assertEqual((ack.world, ack.tick), (w.id, 30))
            f = await w.query_state_async([ids[1]])
            blocking = w.query_state([ids[1]])
            self.assertEqual(f.tick, 30)
            self.assertEqual(f[0].position, blocking[0].position)
            info = await w.info_async()
            self.assertEqual((info.world, info.bodies, info.tick), (w.id, 2, 30))
            snap = await w.save_snapshot_async()
            self.assertIsInstance(snap, bytes)
            await w.step_async(10)
            await w.restore_snapshot_async(snap)
            self.assertEqual((await w.query_state_async([ids[1]]))[0].position,
                             blocking[0].position)
            hello = await self.client.hello_async()
            self.assertEqual(hello.name, "physd-python-api")
            named = await self.client.world_named_async(f"aio-{os.getpid()}")
            self.assertEqual(named, w)
            self.assertFalse(named.created)
            with self.assertRaises(pc.NotFound):
                await self.client.world_named_async("no such world")

        self.run_async(main())

    def test_many_requests_in_flight(self):
        worlds = [self.new_world(f"aio-many{i}", sleep=False) for i in range(8)]

        async def main():
            for w in worlds:
                await w.spawn_async([ground(), box(3.0)])
            # 8 worlds x 25 steps, all sent before any is awaited (200 in flight, inside the
            # daemon's burst of 500 a client).
            futs = [w.step_async(1) for _ in range(25) for w in worlds]
            self.assertTrue(any(not f.done() for f in futs))
            acks = await asyncio.gather(*futs)
            by_world = {}
            for a in acks:
                by_world.setdefault(a.world, []).append(a.tick)
            self.assertEqual(sorted(by_world), sorted(w.id for w in worlds))
            for ticks in by_world.values():
                self.assertEqual(sorted(ticks), list(range(1, 26)))

        self.run_async(main())

    def test_the_loop_runs_while_requests_wait(self):
        # A long step and a quick request of another world: the loop keeps running (a ticker
        # coroutine stamps all through the step), and the quick one is settled first: replies
        # are handed over as they come, not in the order they were sent.
        w = self.new_world("aio-long", sleep=False)
        w.spawn([ground()] + [box(0.5 + 1.2 * k, x=1.2 * i) for i in range(20) for k in range(10)])
        quick = self.new_world("aio-quick")

        async def main():
            stamps = []
            stop = asyncio.Event()

            async def ticker():
                while not stop.is_set():
                    await asyncio.sleep(0.002)
                    stamps.append(time.monotonic())

            t = asyncio.ensure_future(ticker())
            t0 = time.monotonic()
            long = w.step_async(600)
            fast = quick.step_async(1)
            fast_ack = await fast
            long_done_when_fast_came = long.done()
            ack = await long
            t1 = time.monotonic()
            stop.set()
            await t
            return t0, t1, ack, fast_ack, long_done_when_fast_came, stamps

        t0, t1, ack, fast_ack, long_done, stamps = self.run_async(main())
        self.assertEqual((ack.tick, fast_ack.tick), (600, 1))
        self.assertGreater(t1 - t0, 0.1, "the step is too short to show anything")
        self.assertFalse(long_done, "the quick reply waited for the long one")
        inside = [s for s in stamps if t0 + 0.03 < s < t1 - 0.03]
        self.assertGreaterEqual(len(inside), 10, (t1 - t0, len(stamps)))

    def test_errors_cancellation_and_close(self):
        w = self.new_world("aio-errors", sleep=False)
        (body,) = w.spawn(box(2.0))

        async def main():
            with self.assertRaises(pc.InvalidArgument) as cm:
                await w.set_pose_async(body, (math.nan, 0, 1))
            e = cm.exception
            self.assertEqual(e.code, pc.ErrorCode.InvalidArgument)
            self.assertTrue(e.from_server)
            self.assertTrue(e.message)
            with self.assertRaises(pc.NotFound):
                await self.client.world(987654).step_async(1)
            with self.assertRaises(ValueError):       # caught before anything is sent
                w.step_async(1, timeout=-1)
            # A cancelled future: the request still happens; later ones are unaffected.
            fut = w.step_async(5)
            fut.cancel()
            with self.assertRaises(asyncio.CancelledError):
                await fut
            self.assertEqual((await w.step_async(1)).tick, 6)
            # asyncio.wait_for around a request.
            self.assertEqual((await asyncio.wait_for(w.step_async(1), 30)).tick, 7)
            # A client closed with requests in flight: they fail with Disconnected.
            shared = self.new_world("aio-closer", shared=True, sleep=False)
            shared.spawn([ground()] + [box(0.5 + 1.2 * k) for k in range(20)])  # slow steps
            c = DAEMON.client(name="aio-closer")
            await c.connect_async()
            cw = c.world(shared.id)
            pending = [cw.step_async(100) for _ in range(20)]
            c.close()
            outcomes = await asyncio.gather(*pending, return_exceptions=True)
            for o in outcomes:
                self.assertTrue(isinstance(o, pc.Ack) or isinstance(o, pc.Disconnected), o)
            self.assertIn(pc.Disconnected, [type(o) for o in outcomes])
            with self.assertRaises(RuntimeError):
                cw.step_async(1)                     # closed: nothing is sent

        self.run_async(main())
        # Outside a running loop there is no loop to hand the result to.
        with self.assertRaises(RuntimeError):
            w.step_async(1)
        self.assertEqual(w.info().tick, 7)

    def test_frames(self):
        w = self.new_world("aio-frames", sleep=False)
        ids = w.spawn([ground(), box(20.0)])

        async def main():
            with w.subscribe() as sub:
                # A paused world: its whole state at once (tick 0), then nothing until it runs.
                f0 = await sub.wait_for_frame_async(0, timeout=5)
                self.assertEqual((f0.tick, len(f0)), (0, 2))
                self.assertIsNone(await sub.wait_for_frame_async(0, timeout=0.2))
                await w.run_async(60)
                f1 = await sub.wait_for_frame_async(0, timeout=20)
                f2 = await sub.wait_for_frame_async(f1.tick, timeout=20)
                self.assertGreater(f2.tick, f1.tick)
                ticks = []
                async for f in sub:
                    ticks.append(f.tick)
                    self.assertIn(ids[1], f)
                    if len(ticks) == 5:
                        break
                self.assertEqual(ticks, sorted(set(ticks)))
                # A wait cancelled by asyncio.wait_for leaves nothing behind.
                with self.assertRaises(asyncio.TimeoutError):
                    await asyncio.wait_for(sub.wait_for_frame_async(1 << 62, timeout=60), 0.2)
                await w.pause_async()

                # `async for` ends when the subscription closes.
                async def close_soon():
                    await asyncio.sleep(0.2)
                    sub.close()

                closer = asyncio.ensure_future(close_soon())
                more = [f.tick async for f in sub]
                await closer
                self.assertLessEqual(len(more), 1)  # the last frame, if it came after the loop
            self.assertIsNone(await sub.wait_for_frame_async(0, timeout=5))

        self.run_async(main())

    def test_every_request_has_an_async_twin(self):
        # Methods that make no request (or block in the SDK without a future) have none.
        no_twin = {"World": {"id", "subscribe", "created"},
                   "Client": {"close", "closed", "connected", "reconnects", "client_id", "domain",
                              "server", "world", "latest_status", "recent_events", "on_event",
                              "subscribe", "daemons", "duplicate_replies"}}
        for cls in (pc.World, pc.Client):
            for name in dir(cls):
                if name.startswith("_") or name.endswith("_async") or name in no_twin[
                        cls.__name__]:
                    continue
                twin = getattr(cls, name + "_async", None)
                self.assertIsNotNone(
                    twin, f"{cls.__name__}.{name} has no {name}_async: add one in the asyncio "
                          "block of physclient_module.cpp (defineAsync), as step_async, and to "
                          "docs/PYTHON.md's list (or, if it makes no request, to no_twin here)")
                # The same parameters (pybind11's signature line, up to the return type).
                sig = getattr(cls, name).__doc__.splitlines()[0]
                twin_sig = twin.__doc__.splitlines()[0]
                self.assertEqual(sig[len(name):sig.rindex(") ->") + 1],
                                 twin_sig[len(name) + 6:twin_sig.rindex(") ->") + 1],
                                 f"{cls.__name__}.{name}_async")


class Timestamps(WithClient):
    def test_frames_carry_the_servers_time(self):
        w = self.new_world("stamps", sleep=False)
        ids = w.spawn([ground(), box(10.0)])
        got = []
        with w.subscribe(lambda f: got.append((f.stamp_ns, f.stamp))) as sub:
            before = time.time()
            w.run(60)
            f = sub.wait_for_frame(0, timeout=20)
            self.assertTrue(wait_until(lambda: len(got) >= 3, timeout=20))
            w.pause()
        after = time.time()
        self.assertIsNotNone(f)
        for stamp_ns, stamp in got[:3] + [(f.stamp_ns, f.stamp)]:
            self.assertGreater(stamp_ns, 0)
            self.assertEqual(stamp, stamp_ns * 1e-9)
            # The same host's clock: inside the run, with a generous margin.
            self.assertLess(before - 60, stamp)
            self.assertLess(stamp, after + 60)

        async def frames():
            with w.subscribe() as s:
                await w.run_async(60)
                g = await s.wait_for_frame_async(0, timeout=20)
                await w.pause_async()
                return g

        g = asyncio.run(frames())
        self.assertGreater(g.stamp_ns, 0)
        self.assertEqual(g.stamp, g.stamp_ns * 1e-9)
        # A query_state answer carries the server's time too.
        q = w.query_state([ids[1]])
        self.assertGreater(q.stamp_ns, 0)
        self.assertEqual(q.stamp, q.stamp_ns * 1e-9)
        self.assertLess(abs(q.stamp - time.time()), 60)


if __name__ == "__main__":
    unittest.main()
