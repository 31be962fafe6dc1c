#!/usr/bin/env python3
"""Buckling of a pyramid wall on soft contacts: the model of stack stiffening, for one wall.

A pyramid wall (pyramid_20/_40/_100) is one cube thick. On compliant contacts it can lean out
of its plane: each row tilts about the wall's long axis on the springs under it. The model:
row r (0 = bottom, N rows, row r holds N - r cubes of mass m and size L) is rigid; the
interface under it is a rotational spring of stiffness k_rot(r) = points * k * (L/2)^2, the
points at +-L/2 across the wall (4 per cube on the ground, 8 per cube on two cubes below);
gravity destabilizes each tilt theta_r by m g L * (cubes above row r) * theta_r^2 / 2. The
wall stands while K - G (tridiagonal) is positive definite. A soft contact's stiffness is
k = m_eff (2 pi f)^2 with the corner point's effective mass, m/8 between two cubes.

Prints, per height N, the critical contact stiffness and frequency for unit cubes under
9.81 m/s^2. They follow f ~ 0.2 N^1.5 Hz (0.4 N^1.5 sqrt(g/L) / 2 pi). The engine solves
the same model for any stack (physics/dynamics/stacks.h; tests/unit/test_stacks_model.cpp checks
it against the figures printed here) and takes SolverSettings::kStackMargin (1.2) times the
critical frequency, the last column.

Usage: tools/wall_buckling.py [N ...]
"""
import math
import sys


def stands(n, k, m=1000.0, g=9.81, size=1.0):
    """True when a wall of n rows on contact stiffness k (N/m per point) is stable."""
    diag = [0.0] * n
    off = [0.0] * n
    arm2 = (size / 2) ** 2
    for r in range(n):
        points = 4 * n if r == 0 else 8 * (n - r)
        kr = points * k * arm2 * (2 if r == 0 else 1)  # ground contacts: one dynamic body
        diag[r] += kr
        if r > 0:
            diag[r - 1] += kr
            off[r] = -kr
        diag[r] -= m * g * size * (n - r) * (n - r + 1) / 2
    pivot = diag[0]
    if pivot <= 0:
        return False
    for r in range(1, n):
        pivot = diag[r] - off[r] ** 2 / pivot
        if pivot <= 0:
            return False
    return True


def critical(n):
    lo, hi = 1.0, 1e14
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        if stands(n, mid):
            hi = mid
        else:
            lo = mid
    return hi


def main():
    heights = [int(a) for a in sys.argv[1:]] or [10, 20, 40, 60, 80, 100, 150]
    m_eff = 1000.0 / 8
    print("rows  k_crit (N/m)  f_crit (Hz)  0.2 N^1.5  stack stiffening (Hz)")
    for n in heights:
        k = critical(n)
        f = math.sqrt(k / m_eff) / (2 * math.pi)
        print(f"{n:4d}  {k:12.3g}  {f:11.1f}  {0.2 * n ** 1.5:9.1f}  "
              f"{1.2 * f:21.1f}")


if __name__ == "__main__":
    main()
