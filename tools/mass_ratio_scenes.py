#!/usr/bin/env python3
"""Writes configs/scenes/mass_ratio_{10,100,1000}.json (issue 23): heavy bodies carried by
light ones at R:1, four setups side by side (a column, a plate on four supports, a beam on two,
a cube on a pile). Run from the repository root: python3 tools/mass_ratio_scenes.py"""
import json, sys
def box(name, pos, he, mass=None):
    b = {"name": name, "position": pos, "shapes": [{"type": "box", "half_extents": he}]}
    if mass is not None: b["mass"] = mass
    return b
def scene(R):
    bodies = [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]}]
    # A: a column of two light 1 m cubes (1000 kg) under a heavy cube.
    bodies += [box("stack/light0", [0, 0, 0.5], [0.5]*3), box("stack/light1", [0, 0, 1.5], [0.5]*3),
               box("stack/heavy", [0, 0, 2.5], [0.5]*3, 1000.0 * R)]
    # B: a heavy 4 x 4 x 0.2 m plate on four 0.4 m cubes (64 kg) at its corners.
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (-1, 1), (1, 1)]):
        bodies.append(box(f"plate/support{i}", [10 + 1.6 * sx, 1.6 * sy, 0.2], [0.2]*3))
    bodies.append(box("plate/heavy", [10, 0, 0.5], [2, 2, 0.1], 64.0 * R))
    # C: a heavy 6 m beam (0.5 x 0.5) on two 0.5 m cubes (125 kg) near its ends.
    bodies += [box("beam/support0", [17.5, 0, 0.25], [0.25]*3), box("beam/support1", [22.5, 0, 0.25], [0.25]*3),
               box("beam/heavy", [20, 0, 0.75], [3, 0.25, 0.25], 125.0 * R)]
    # D: a heavy cube on a pile of light 1 m cubes: 3 x 3 under 2 x 2 under it.
    for i in range(3):
        for j in range(3):
            bodies.append(box(f"pile/base{3*i+j}", [30 + (i - 1) * 1.0, (j - 1) * 1.0, 0.5], [0.5]*3))
    for i in range(2):
        for j in range(2):
            bodies.append(box(f"pile/mid{2*i+j}", [30 + (i - 0.5) * 1.0, (j - 0.5) * 1.0, 1.5], [0.5]*3))
    bodies.append(box("pile/heavy", [30, 0, 2.5], [0.5]*3, 1000.0 * R))
    return {
        "name": f"mass_ratio_{R}",
        "description": (f"Heavy bodies carried by light ones at {R}:1, side by side: a 1 m cube of "
            f"{R} x 1000 kg on a column of two 1000 kg cubes; a 4 x 4 x 0.2 m plate of {R} x 64 kg on "
            f"four 0.4 m cubes of 64 kg at its corners; a 6 m beam of {R} x 125 kg on two 0.5 m cubes of "
            f"125 kg; a 1 m cube of {R} x 1000 kg on a pile of 1000 kg cubes (3 x 3 under 2 x 2). mu 0.6, "
            "no sleeping. Passes when for 10 s no heavy body or support moves more than 1 cm sideways and "
            "no contact penetrates more than 1 cm."),
        "duration": 10,
        "sleep": False,
        "materials": {"default": {"friction": 0.6, "restitution": 0, "density": 1000}},
        "bodies": bodies,
        "metrics": {"top_bodies": ["stack/heavy", "stack/light0", "stack/light1", "plate/heavy", "plate/support*",
                                   "beam/heavy", "beam/support*", "pile/heavy", "pile/mid*", "pile/base*"],
                    "settle_time": 1},
        "criteria": [
            {"metric": "top_drift", "max": 0.01},
            {"metric": "penetration_max", "max": 0.01},
            {"metric": "nan", "max": 0}
        ]
    }
for R in (10, 100, 1000):
    with open(f"configs/scenes/mass_ratio_{R}.json", "w") as f:
        f.write(json.dumps(scene(R), indent=1) + "\n")
