#!/usr/bin/env python3
"""Writes configs/scenes/ragdoll_pile.json (issue 41): a jointed pile. Eight ragdolls of two
sizes (1.0 and 0.6 times a 1.8 m figure), 15 bodies each (capsule pelvis, chest and limbs,
sphere head and hands, box feet) on ball joints (neck, shoulders, wrists, hips) and limited
hinges (elbows, knees, ankles), dropped lying in four crossed layers of two into a 2 x 2 m
bin of static boxes. A small ragdoll's hand (0.08 kg) touches a large one's chest (35 kg):
pairs ten to 430 times apart in mass, in one heap. Deterministic (no random numbers: each
ragdoll's pose follows from its index). Run from the repository root:
python3 tools/ragdoll_pile_scene.py
(with arguments LAYERS PER_LAYER HALF_WIDTH OUT [SIZES,...]: a variant, for experiments;
docs/BENCHMARKS.md, "Jointed piles", measured twelve.)"""
import json, math

DENSITY = 1000.0


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz]


def qaxis(axis, angle):
    n = math.sqrt(sum(c * c for c in axis))
    s = math.sin(angle / 2) / n
    return [axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2)]


def rot(q, v):
    # v' = q v q*
    p = qmul(qmul(q, [v[0], v[1], v[2], 0.0]), [-q[0], -q[1], -q[2], q[3]])
    return p[:3]


def r6(x):
    return round(x, 6)


def ragdoll(k, s, q, origin, bodies, joints):
    """One ragdoll standing in its own frame (z up, feet at z = 0, facing +y), scaled by s,
    turned by q and moved to origin. Every capsule lies along its body's local z."""
    name = f"doll{k}"

    def place(p):
        w = rot(q, [c * s for c in p])
        return [r6(w[i] + origin[i]) for i in range(3)]

    def body(part, p, shape):
        bodies.append({"name": f"{name}/{part}", "position": place(p),
                       "rotation": [r6(c) for c in q], "shapes": [shape]})

    def capsule(r, top, bottom):  # a vertical capsule from z = top to z = bottom (caps included)
        return {"type": "capsule", "radius": r6(r * s), "half_height": r6((top - bottom - 2 * r) / 2 * s)}

    def sphere(r):
        return {"type": "sphere", "radius": r6(r * s)}

    body("pelvis", [0, 0, 0.90], capsule(0.12, 1.10, 0.70))
    body("chest", [0, 0, 1.35], capsule(0.15, 1.65, 1.05))
    body("head", [0, 0, 1.75], sphere(0.10))
    for side, x in (("l", -0.23), ("r", 0.23)):
        body(f"upper_arm_{side}", [x, 0, 1.40], capsule(0.045, 1.55, 1.25))
        body(f"forearm_{side}", [x, 0, 1.115], capsule(0.04, 1.25, 0.98))
        body(f"hand_{side}", [x, 0, 0.935], sphere(0.045))
    for side, x in (("l", -0.09), ("r", 0.09)):
        body(f"thigh_{side}", [x, 0, 0.59], capsule(0.07, 0.78, 0.40))
        body(f"shin_{side}", [x, 0, 0.23], capsule(0.055, 0.40, 0.06))
        bodies.append({"name": f"{name}/foot_{side}", "position": place([x, 0.04, 0.03]),
                       "rotation": [r6(c) for c in q],
                       "shapes": [{"type": "box", "half_extents": [r6(0.04 * s), r6(0.09 * s), r6(0.03 * s)]}]})

    def joint(kind, a, b, anchor, axis=None, limit=None):
        j = {"type": kind, "body_a": f"{name}/{a}", "body_b": f"{name}/{b}", "anchor_world": place(anchor)}
        if axis is not None:
            j["axis_world"] = [r6(c) for c in rot(q, axis)]
        if limit is not None:
            j["limit"] = {"lower": limit[0], "upper": limit[1]}
        joints.append(j)

    joint("ball", "pelvis", "chest", [0, 0, 1.08])
    joint("ball", "chest", "head", [0, 0, 1.65])
    for side, x in (("l", -0.23), ("r", 0.23)):
        joint("ball", "chest", f"upper_arm_{side}", [x, 0, 1.55])
        joint("hinge", f"upper_arm_{side}", f"forearm_{side}", [x, 0, 1.25], [1, 0, 0], [0.0, 2.4])
        joint("ball", f"forearm_{side}", f"hand_{side}", [x, 0, 0.98])
    for side, x in (("l", -0.09), ("r", 0.09)):
        joint("ball", "pelvis", f"thigh_{side}", [x, 0, 0.78])
        joint("hinge", f"thigh_{side}", f"shin_{side}", [x, 0, 0.40], [1, 0, 0], [-2.4, 0.0])
        joint("hinge", f"shin_{side}", f"foot_{side}", [x, 0, 0.06], [1, 0, 0], [-0.5, 0.5])


def static_box(name, pos, he):
    return {"name": name, "type": "static", "position": pos, "shapes": [{"type": "box", "half_extents": he}]}


def scene(layers=4, per_layer=2, half=1.0, sizes=(1.0, 0.6)):
    H = half
    bodies = [static_box("bin/floor", [0, 0, -0.1], [H + 0.2, H + 0.2, 0.1])]
    for i, (x, y, hx, hy) in enumerate([(-H - 0.1, 0, 0.1, H + 0.2), (H + 0.1, 0, 0.1, H + 0.2),
                                         (0, -H - 0.1, H, 0.1), (0, H + 0.1, H, 0.1)]):
        bodies.append(static_box(f"bin/wall{i}", [x, y, 0.6], [hx, hy, 0.6]))
    joints = []
    k = 0
    for layer in range(layers):
        for slot in range(per_layer):
            s = sizes[(layer + slot) % len(sizes)]
            # Lying face down (the standing figure turned 90 degrees about x: head to +y), then
            # every other layer crossed (a quarter turn about z), each doll a little yawed and
            # rolled so the heap is not a lattice.
            q = qaxis([1, 0, 0], -math.pi / 2)
            q = qmul(qaxis([0, 1, 0], 0.3 * (slot - 1) + 0.2 * layer), q)
            q = qmul(qaxis([0, 0, 1], (math.pi / 2) * (layer % 2) + 0.15 * (slot - 1) - 0.1 * (layer - 1.5)), q)
            # The pelvis (0.9 s above the feet) over the slot's centre.
            c = rot(q, [0, 0, 0.9 * s])
            lateral = (slot - (per_layer - 1) / 2) * 0.85
            centre = [lateral, 0.0] if layer % 2 == 0 else [0.0, lateral]
            z = 0.45 + 0.55 * layer
            ragdoll(k, s, q, [r6(centre[0] - c[0]), r6(centre[1] - c[1]), r6(z - c[2])], bodies, joints)
            k += 1
    return {
        "name": "ragdoll_pile",
        "description": (
            "A jointed pile (issue 41): eight ragdolls of two sizes (1.0 and 0.6 times a 1.8 m "
            "figure; 15 bodies each: capsule pelvis, chest and limbs, sphere head and hands, box "
            "feet) on ball joints (neck, shoulders, wrists, hips) and limited hinges (elbows, "
            "knees, ankles), dropped lying in four crossed layers of two into a 2 x 2 m bin of "
            "static boxes; light hands and feet touch heavy chests (a 0.08 kg hand, a 35 kg "
            "chest). mu 0.6, no sleeping, 10 s (written by tools/ragdoll_pile_scene.py). Passes "
            "when after 4 s no contact penetrates 2 mm or more, no joint opens by 2 cm, nothing "
            "moves faster than 10 m/s and there is no NaN."),
        "duration": 10,
        "sleep": False,
        "materials": {"default": {"friction": 0.6, "restitution": 0, "density": DENSITY}},
        "bodies": bodies,
        "joints": joints,
        "metrics": {"settle_time": 4},
        "criteria": [
            {"metric": "penetration_settled_max", "max": 0.002},
            {"metric": "joint_error_max", "max": 0.02},
            {"metric": "max_speed", "max": 10},
            {"metric": "nan", "max": 0},
        ],
    }


if __name__ == "__main__":
    import sys
    if len(sys.argv) > 1:  # experiments: layers per_layer half out
        with open(sys.argv[4], "w") as f:
            f.write(json.dumps(scene(int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), *([tuple(float(x) for x in sys.argv[5].split(','))] if len(sys.argv) > 5 else [])), indent=1) + "\n")
    else:
        with open("configs/scenes/ragdoll_pile.json", "w") as f:
            f.write(json.dumps(scene(), indent=1) + "\n")
