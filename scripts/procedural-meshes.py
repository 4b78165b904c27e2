#!/usr/bin/env python3
"""Writes the procedural meshes shipped in config/geometry/ (run from the repository root).

- corrugated-sample.obj: the paper's corrugated sample, as config/geometry/corrugated-d5100.toml
  describes it analytically: a 10 cm square sheet in its local XY plane, height
  a·sin(2πx/period) with a = 6 mm and a 30 mm period, with its exact normals at the vertices.
- grooved-block.obj: a concave test part: a 60 mm square block 15 mm thick whose top has three
  V-grooves, 90° wide and 5 mm deep, running along Y; flat faces (no normals: the faces' own).
  Its grooves' walls see only part of the sky, which is what self-occlusion is tested on.

Both are in millimetres (`units = "mm"` in a geometry file), their origin at the centre of
their top face, +Z up out of it.
"""

import math


def corrugated(path, half=50.0, amplitude=6.0, period=30.0, nx=150, ny=10):
    with open(path, "w") as f:
        f.write("# The paper's corrugated sample (scripts/procedural-meshes.py), millimetres.\n")
        for j in range(ny + 1):
            y = -half + 2 * half * j / ny
            for i in range(nx + 1):
                x = -half + 2 * half * i / nx
                k = 2 * math.pi / period
                z = amplitude * math.sin(k * x)
                f.write(f"v {x:.6f} {y:.6f} {z:.6f}\n")
        for j in range(ny + 1):
            for i in range(nx + 1):
                x = -half + 2 * half * i / nx
                k = 2 * math.pi / period
                slope = amplitude * k * math.cos(k * x)
                n = math.sqrt(1 + slope * slope)
                f.write(f"vn {-slope / n:.6f} 0 {1 / n:.6f}\n")
        at = lambda i, j: j * (nx + 1) + i + 1
        for j in range(ny):
            for i in range(nx):
                a, b, c, d = at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)
                f.write(f"f {a}//{a} {b}//{b} {d}//{d}\n")
                f.write(f"f {a}//{a} {d}//{d} {c}//{c}\n")


def grooved(path, half=30.0, thick=15.0, depth=5.0, grooves=3):
    # The top's profile along X: flats between V-grooves of 90° (half-width = depth).
    pitch = 2 * half / grooves
    xs, zs = [-half], [0.0]
    for g in range(grooves):
        centre = -half + pitch * (g + 0.5)
        for x, z in [(centre - depth, 0.0), (centre, -depth), (centre + depth, 0.0)]:
            xs.append(x)
            zs.append(z)
    xs.append(half)
    zs.append(0.0)
    n = len(xs)
    verts = []
    for y in (-half, half):
        for x, z in zip(xs, zs):
            verts.append((x, y, z))
    # The bottom's four corners.
    for y in (-half, half):
        for x in (-half, half):
            verts.append((x, y, -thick))
    top = lambda i, side: side * n + i + 1  # side 0 at y = −half, 1 at +half
    bottom = lambda x_side, y_side: 2 * n + y_side * 2 + x_side + 1
    faces = []
    # The top's strips, facing up.
    for i in range(n - 1):
        faces.append((top(i, 0), top(i + 1, 0), top(i + 1, 1)))
        faces.append((top(i, 0), top(i + 1, 1), top(i, 1)))
    # The two end walls (y = ±half): the profile over the bottom edge, as a fan from a
    # bottom corner, then the last triangle to the other.
    for side, flip in ((0, False), (1, True)):
        b0, b1 = bottom(0, side), bottom(1, side)
        for i in range(n - 1):
            t = (b0, top(i + 1, side), top(i, side))
            faces.append(t[::-1] if flip else t)
        t = (b0, b1, top(n - 1, side))
        faces.append(t[::-1] if flip else t)
    # The side walls (x = ±half) and the bottom.
    faces.append((top(0, 0), top(0, 1), bottom(0, 1)))
    faces.append((top(0, 0), bottom(0, 1), bottom(0, 0)))
    faces.append((top(n - 1, 0), bottom(1, 0), bottom(1, 1)))
    faces.append((top(n - 1, 0), bottom(1, 1), top(n - 1, 1)))
    faces.append((bottom(0, 0), bottom(0, 1), bottom(1, 1)))
    faces.append((bottom(0, 0), bottom(1, 1), bottom(1, 0)))
    with open(path, "w") as f:
        f.write("# A block with three 90-degree V-grooves (scripts/procedural-meshes.py), millimetres.\n")
        for v in verts:
            f.write("v %.6f %.6f %.6f\n" % v)
        for t in faces:
            f.write("f %d %d %d\n" % t)


if __name__ == "__main__":
    corrugated("config/geometry/corrugated-sample.obj")
    grooved("config/geometry/grooved-block.obj")
