#!/usr/bin/env python3
"""Drop a few boxes on a ground plane with physd and print where they came to rest.

    build/server/physd --config configs/physd.toml &
    PYTHONPATH=build/client_sdk/python python3 client_sdk/python/examples/drop_boxes.py

--domain and --cyclone-xml (a Cyclone DDS XML file) name the daemon's DDS domain and
configuration: configs/physd.toml's are domain 0 and configs/cyclonedds/loopback.xml.
"""
import argparse
import sys

import physclient as pc


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--cyclone-xml", help="Cyclone DDS XML file (default: CYCLONEDDS_URI)")
    parser.add_argument("--boxes", type=int, default=3)
    parser.add_argument("--steps", type=int, default=180)
    args = parser.parse_args(argv)
    xml = open(args.cyclone_xml).read() if args.cyclone_xml else None

    try:
        with pc.Client(domain=args.domain, name="drop_boxes", cyclone_xml=xml) as client:
            server = client.connect()
            print(f"connected to {server.name} {server.version}")

            # Worlds are durable (kept on physd's disk until destroyed): the end of the with
            # block destroys this one (docs/PYTHON.md "Worlds are durable").
            with client.create_world(f"drop-boxes-{client.client_id % 100000}") as world:
                ground = pc.BodyDef(type="static",
                                    shapes=[pc.ShapeDef(pc.ShapeGeom.plane((0, 0, 1), 0))])
                boxes = [pc.BodyDef(position=(0, 0, 1 + 1.5 * i),
                                    shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.5, 0.5, 0.5)))])
                         for i in range(args.boxes)]
                ids = world.spawn([ground] + boxes)
                print(f"world {world.id}: spawned {len(ids)} bodies")

                ack = world.step(args.steps)
                frame = world.query_state(ids[1:])
                print(f"tick {ack.tick}, t = {frame.time:.2f} s")
                for i, body in enumerate(frame):
                    x, y, z = body.position
                    print(f"box {i}: x={x:.3f} y={y:.3f} z={z:.3f}")
    except pc.Error as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
