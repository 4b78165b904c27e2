#!/usr/bin/env python3
"""brdfd's own outside test set: parts as they come (concave, brushed, two materials, a
coated and sheened paint), rendered by Mitsuba 3 (PyPI `mitsuba`), whose path tracer draws the
light a part's surface reflects onto itself, and scored by relighting brdfd's estimates under
maps the estimate was not fitted to (docs/evaluation.md, "brdfd's own Mitsuba set").

    python mitsuba-scenes.py render MAPS OUT [--spp N] [--photos-only] [SCENE...]
    python mitsuba-scenes.py score MAPS OUT BRDFD [SCENE...]

MAPS is a folder of equirectangular Radiance maps (the reference data's `envmaps/`): the
photo is taken under courtyard.hdr and each estimate relit under every other .hdr there.

`render` writes OUT/SCENE/ for each scene (all of them if none is named):

- part.obj, geometry.toml: the part (metres, in brdfd's world) and the camera, as a brdfd
  geometry file, so that `brdfd estimate --geometry OUT/SCENE/geometry.toml` sees what
  Mitsuba rendered;
- photo.exr: linear radiance under the capture map, with up to two bounces off the part;
- truth-MAP.exr: the same under each held-out map, the relighting's truth;
- direct-photo.exr, direct-MAP.exr (concave parts): direct light only, what a part without
  interreflection would look like;

  (`--photos-only` renders neither truth-MAP.exr nor direct-MAP.exr: a test that needs only
  the photos; such a set cannot be scored);
- regions.exr: which region each pixel shows (0 the background, then 1, 2, ...: the two
  materials, or a concave part's grooves apart from the rest);
- scene.json: the scene's truth (materials, grain direction and roughness ratio, which
  assumptions of brdfd's model it breaks).

`score` estimates each scene with the brdfd binary BRDFD (default settings), relights it with
`brdfd render` under every held-out map, and prints the relative RMSE over the part's pixels
(the evaluation's relight error, on 4 × 4 blocks) per map and region, how many materials the
estimate found and, on a part of several, how its split (`materials-mask.png`) matches the
truth's regions (IoU); it writes OUT/scores.json.

Conventions (docs/formats.md): brdfd's world has +Y up; its map's middle column is at -Z,
Mitsuba's at +Z, so the map is turned half a turn about +Y. Both cameras look along
look_at - position with +Y up, the image's x to the right and y down; the pinhole's principal
point is the image centre. The background is black (the map is not seen directly), as brdfd's
renders of a part are.
"""

import array
import json
import math
import os
import subprocess
import sys

import mitsuba as mi

CAPTURE = "courtyard"


def held_out(maps):
    """The maps the estimates are relit under: every map in MAPS but the capture's."""
    return sorted(f[:-4] for f in os.listdir(maps) if f.endswith(".hdr") and f[:-4] != CAPTURE)

# The camera: a 480 × 320 pinhole half a metre from the part, a little above it.
WIDTH, HEIGHT, FX = 480, 320, 2000.0
POSITION = [0.0, 0.12, 0.5]
LOOK_AT = [0.0, 0.0, 0.0]
# The part's own +Z (out of its top) leans back by this much toward the camera and the sky.
TILT_DEG = 35.0
# Path depth: 2 is direct light, 4 adds two bounces off the part itself.
BOUNCES_DEPTH, DIRECT_DEPTH = 4, 2

# Materials (Mitsuba's BSDFs). The plastics are GGX over a diffuse base, the metals GGX
# conductors with measured complex indices of refraction.
BLUE_PLASTIC = {"type": "roughplastic", "distribution": "ggx", "alpha": 0.12, "int_ior": 1.5,
                "diffuse_reflectance": {"type": "rgb", "value": [0.08, 0.16, 0.45]}}
WARM_PLASTIC = {"type": "roughplastic", "distribution": "ggx", "alpha": 0.1, "int_ior": 1.5,
                "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.45, 0.3]}}
GOLD = {"type": "roughconductor", "material": "Au", "distribution": "ggx", "alpha": 0.2}
# A Lambertian paint, which brdfd's glTF renderer draws exactly: the grooves' bounced light
# checks brdfd's bounces against the path tracer's, with nothing of the estimate in it.
MATTE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}}
COAT_SHEEN = {"type": "principled", "base_color": {"type": "rgb", "value": [0.5, 0.08, 0.06]},
              "roughness": 0.45, "clearcoat": 1.0, "clearcoat_gloss": 0.9, "sheen": 1.0,
              "sheen_tint": 0.0}
# Brushed aluminium: smooth along the grain (the tangent, u), rough across it.
GRAIN_DEG = 30.0
ALPHA_ALONG, ALPHA_ACROSS = 0.06, 0.24
BRUSHED = {"type": "roughconductor", "material": "Al", "distribution": "ggx",
           "alpha_u": ALPHA_ALONG, "alpha_v": ALPHA_ACROSS}

# Each scene: its part, its materials by region, the assumptions of brdfd's model it breaks.
SCENES = {
    "dome-plastic": ("dome", [("blue plastic", BLUE_PLASTIC)], []),
    "dome-gold": ("dome", [("gold", GOLD)], []),
    "dome-coat-sheen": ("dome", [("red paint, clear coat and sheen", COAT_SHEEN)], []),
    "groove-plastic": ("grooved", [("warm plastic", WARM_PLASTIC)], ["interreflection"]),
    "groove-gold": ("grooved", [("gold", GOLD)], ["interreflection"]),
    "groove-matte": ("grooved", [("matte paint", MATTE)], ["interreflection"]),
    "brushed-aluminium": ("brushed", [("brushed aluminium", BRUSHED)], ["anisotropy"]),
    "two-tone": ("striped", [("blue plastic", BLUE_PLASTIC), ("gold", GOLD)],
                 ["several materials"]),
}


def to_world(p):
    """A point of the part's frame (millimetres, +Z out of its top) in brdfd's world (metres):
    tipped back about X by TILT_DEG."""
    t = math.radians(-TILT_DEG)
    x, y, z = (c / 1000.0 for c in p)
    return (x, y * math.cos(t) - z * math.sin(t), y * math.sin(t) + z * math.cos(t))


def dome_points(rings=60, segments=180, radius=30.0, cap_deg=60.0):
    """A spherical cap 30 mm in radius at its base, 60° from its top to its edge, closed by a
    flat base: (vertices, triangles) in the part's frame. Triangles are wound outward."""
    big = radius / math.sin(math.radians(cap_deg))
    drop = big * math.cos(math.radians(cap_deg))
    verts = [(0.0, 0.0, big - drop)]
    for r in range(1, rings + 1):
        polar = math.radians(cap_deg) * r / rings
        for s in range(segments):
            a = 2 * math.pi * s / segments
            verts.append((big * math.sin(polar) * math.cos(a), big * math.sin(polar) * math.sin(a),
                          big * math.cos(polar) - drop))
    ring = lambda r, s: 1 + (r - 1) * segments + s % segments
    tris = [(0, ring(1, s), ring(1, s + 1)) for s in range(segments)]
    for r in range(1, rings):
        for s in range(segments):
            a, b, c, d = ring(r, s), ring(r, s + 1), ring(r + 1, s), ring(r + 1, s + 1)
            tris += [(a, c, d), (a, d, b)]
    base = len(verts)
    verts.append((0.0, 0.0, 0.0))
    tris += [(base, ring(rings, s + 1), ring(rings, s)) for s in range(segments)]
    return verts, tris


def grooved_points(half=35.0, step=0.35, depth=8.0, angle_deg=60.0, floor=1.0,
                   centres=(-20.0, 0.0, 20.0), radius=120.0):
    """A gently domed 70 mm square top (radius of curvature 120 mm) cut by three grooves along
    Y, 8 mm deep, whose walls lean 60° apart and face each other over a 1 mm floor: a
    heightfield in the part's frame, with each triangle's region (1 the rest, 2 the grooves).
    The grooves' edges and floors are grid lines, so that their creases are sharp. The floor
    keeps every crease obtuse: where two walls meet at an acute angle, Mitsuba's rays leave
    a point near the crease from the far side of the other wall, and a glossy metal shows a
    bright line of sky there that no light reaches."""
    w = depth * math.tan(math.radians(angle_deg / 2))
    xs = {round(-half + step * i, 6) for i in range(int(2 * half / step) + 1)}
    for c in centres:
        xs |= {c - w - floor / 2, c - floor / 2, c + floor / 2, c + w + floor / 2}
    xs = sorted(xs)
    ys = [-half + step * i for i in range(int(2 * half / step) + 1)]

    def groove(x):
        return max((depth * min(1.0, (w + floor / 2 - abs(x - c)) / w) for c in centres
                    if abs(x - c) < w + floor / 2), default=0.0)

    def height(x, y):
        return -(x * x + y * y) / (2 * radius) - groove(x)

    verts = [(x, y, height(x, y)) for y in ys for x in xs]
    n = len(xs)
    tris, regions = [], []
    for j in range(len(ys) - 1):
        for i in range(n - 1):
            a, b, c, d = j * n + i, j * n + i + 1, (j + 1) * n + i, (j + 1) * n + i + 1
            middle = (xs[i] + xs[i + 1]) / 2
            in_groove = any(abs(middle - c) < w + floor / 2 for c in centres)
            tris += [(a, b, d), (a, d, c)]
            regions += [2 if in_groove else 1] * 2
    return verts, tris, regions


def stripe_regions(verts, tris, width=20.0, angle_deg=-40.0):
    """The dome's triangles in a straight stripe through its top (region 2) or not (1)."""
    a = math.radians(angle_deg)
    out = []
    for t in tris:
        cx = sum(verts[i][0] for i in t) / 3
        cy = sum(verts[i][1] for i in t) / 3
        out.append(2 if abs(-cx * math.sin(a) + cy * math.cos(a)) < width / 2 else 1)
    return out


def grain_uv(p):
    """Texture coordinates whose u runs along the grain: the part's X turned by GRAIN_DEG
    about its Z (planar, so the tangent is the grain's direction laid on the surface)."""
    g = math.radians(GRAIN_DEG)
    return ((p[0] * math.cos(g) + p[1] * math.sin(g)) / 100.0,
            (-p[0] * math.sin(g) + p[1] * math.cos(g)) / 100.0)


def write_obj(path, verts, tris, uvs=None):
    with open(path, "w") as f:
        f.write("# brdfd's Mitsuba set (scripts/mitsuba-scenes.py): metres, brdfd's world.\n")
        for v in verts:
            f.write("v %.7f %.7f %.7f\n" % to_world(v))
        for uv in uvs or []:
            f.write("vt %.7f %.7f\n" % uv)
        for t in tris:
            if uvs:
                f.write("f %d/%d %d/%d %d/%d\n" % tuple(k + 1 for i in t for k in (i, i)))
            else:
                f.write("f %d %d %d\n" % tuple(i + 1 for i in t))


def part(kind):
    """The part's vertices, triangles, region per triangle and texture coordinates."""
    if kind == "grooved":
        verts, tris, regions = grooved_points()
        return verts, tris, regions, None
    verts, tris = dome_points()
    regions = stripe_regions(verts, tris) if kind == "striped" else [1] * len(tris)
    uvs = [grain_uv(v) for v in verts] if kind == "brushed" else None
    return verts, tris, regions, uvs


def geometry_toml():
    return f"""# brdfd's Mitsuba set (scripts/mitsuba-scenes.py): the camera Mitsuba rendered with.
[camera]
type = "pinhole"
width = {WIDTH}
height = {HEIGHT}
fx = {FX}
fy = {FX}
cx = {WIDTH / 2}
cy = {HEIGHT / 2}
position = {POSITION}
look_at = {LOOK_AT}
up = [0.0, 1.0, 0.0]

[shape]
type = "mesh"
file = "part.obj"
units = "m"
"""


def sensor(spp):
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": 2 * math.degrees(math.atan(WIDTH / 2 / FX)),
        "to_world": mi.ScalarTransform4f().look_at(origin=POSITION, target=LOOK_AT,
                                                   up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": WIDTH, "height": HEIGHT,
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": spp},
    }


def render(shapes, integrator, spp, map_path=None, seed=0):
    scene = {"type": "scene", "integrator": integrator, "sensor": sensor(spp)}
    if map_path:
        scene["light"] = {"type": "envmap", "filename": map_path,
                          "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 180)}
    scene.update(shapes)
    return mi.render(mi.load_dict(scene), seed=seed)


def write_exr(path, image):
    mi.Bitmap(image).write(path)


def render_scene(maps, out, name, spp, truths=True):
    kind, materials, breaks = SCENES[name]
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    verts, tris, regions, uvs = part(kind)
    write_obj(os.path.join(d, "part.obj"), verts, tris, uvs)
    with open(os.path.join(d, "geometry.toml"), "w") as f:
        f.write(geometry_toml())
    # Mitsuba gets the part as one mesh per region, each with its material: a concave part's
    # grooves are a region of the same material, so that the score can tell them apart.
    shapes, ids = {}, {}
    for r in sorted(set(regions)):
        path = os.path.join(d, f"region-{r}.obj")
        keep = [t for t, tr in zip(tris, regions) if tr == r]
        write_obj(path, verts, keep, uvs)
        bsdf = materials[min(r, len(materials)) - 1][1]
        shapes[f"region{r}"] = {"type": "obj", "filename": path, "face_normals": True,
                                "bsdf": bsdf}
        # For regions.exr: region r shines r (units of radiance), the rest is black.
        ids[f"region{r}"] = {"type": "obj", "filename": path, "face_normals": True,
                             "bsdf": {"type": "diffuse", "reflectance": 0.0},
                             "emitter": {"type": "area", "radiance": float(r)}}
    path = lambda depth: {"type": "path", "max_depth": depth, "hide_emitters": True}
    concave = "interreflection" in breaks
    capture = os.path.join(maps, CAPTURE + ".hdr")
    write_exr(os.path.join(d, "photo.exr"), render(shapes, path(BOUNCES_DEPTH), spp, capture))
    if concave:
        write_exr(os.path.join(d, "direct-photo.exr"),
                  render(shapes, path(DIRECT_DEPTH), spp, capture))
    for m in held_out(maps) if truths else []:
        held = os.path.join(maps, m + ".hdr")
        write_exr(os.path.join(d, f"truth-{m}.exr"),
                  render(shapes, path(BOUNCES_DEPTH), spp, held, seed=1))
        if concave:
            write_exr(os.path.join(d, f"direct-{m}.exr"),
                      render(shapes, path(DIRECT_DEPTH), spp, held, seed=1))
    # One sample at each pixel's centre would alias the silhouette less than brdfd's own
    # mask does; a few, averaged, leave mixed pixels at the edges, which the score drops.
    write_exr(os.path.join(d, "regions.exr"),
              render(ids, {"type": "direct", "hide_emitters": False}, 16))
    truth = {
        "scene": name,
        "part": kind,
        "triangles": len(tris),
        "regions": {str(r): materials[min(r, len(materials)) - 1][0] if len(materials) > 1
                    else ("grooves" if r == 2 else "the rest") for r in sorted(set(regions))},
        "materials": [{"name": n, "mitsuba": m} for n, m in materials],
        "breaks": breaks,
        "capture": CAPTURE,
        "held_out": held_out(maps) if truths else [],
        "photos_only": not truths,
        "samples_per_pixel": spp,
        "bounces": BOUNCES_DEPTH - DIRECT_DEPTH,
        "mitsuba": mi.__version__,
    }
    if kind == "brushed":
        g = math.radians(GRAIN_DEG)
        a = to_world((math.cos(g), math.sin(g), 0.0))
        n = math.sqrt(sum(c * c for c in a))
        truth["grain"] = {"degrees_from_part_x": GRAIN_DEG,
                          "world_direction_at_top": [c / n for c in a],
                          "world_normal_at_top": list(to_world((0.0, 0.0, 1000.0))),
                          "alpha_along": ALPHA_ALONG, "alpha_across": ALPHA_ACROSS}
    with open(os.path.join(d, "scene.json"), "w") as f:
        json.dump(truth, f, indent=2)
    print(f"{name}: {len(tris)} triangles, {d}", flush=True)


def read_rgb(path):
    b = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                                srgb_gamma=False)
    t = mi.TensorXf(b)
    return array.array("f", t.array), t.shape[1]


# The score compares 4 × 4 blocks of pixels: the path tracer's noise (about 0.1 of a pixel's
# radiance at 512 samples) falls 4 times, and the part, about 70 blocks across, is seen at
# the evaluation's own resolution (its spheres are 64 pixels wide).
BLOCK = 4


def blocks(region, width, height):
    """The 4 × 4 blocks wholly inside one region (every pixel's samples on it): each block's
    region and pixel indices."""
    out = []
    for by in range(height // BLOCK):
        for bx in range(width // BLOCK):
            px = [(by * BLOCK + y) * width + bx * BLOCK + x
                  for y in range(BLOCK) for x in range(BLOCK)]
            r = {region.get(p, 0) for p in px}
            if len(r) == 1 and 0 not in r:
                out.append((r.pop(), px))
    return out


def relative_rmse(ours, truth, kept):
    """The evaluation's relight error, √(Σ (ours − truth)² / Σ truth²), over the channels of
    the kept blocks' means."""
    num = den = 0.0
    for _, px in kept:
        for c in range(3):
            a = sum(ours[3 * p + c] for p in px) / len(px)
            b = sum(truth[3 * p + c] for p in px) / len(px)
            num += (a - b) ** 2
            den += b * b
    return math.sqrt(num / den) if den > 0 else float("nan")


def grain_error(truth, found):
    """How far brdfd's grain is from the truth, on the dome's top (both laid on the surface
    there: a grain's component along the normal does not turn the tangent), and its
    stretch (alpha across / alpha along) against the truth's."""
    n = truth["world_normal_at_top"]
    length = math.sqrt(sum(c * c for c in n))
    n = [c / length for c in n]

    def laid(g):
        d = sum(a * b for a, b in zip(g, n))
        t = [a - d * b for a, b in zip(g, n)]
        length = math.sqrt(sum(c * c for c in t))
        if length == 0:
            raise SystemExit("a grain along the dome's normal has no direction on its top")
        return [c / length for c in t]

    cos = abs(sum(a * b for a, b in zip(laid(truth["world_direction_at_top"]),
                                        laid(found["grain"]))))
    return {"degrees_off": math.degrees(math.acos(min(1.0, cos))),
            "stretch": found["alpha_across"] / found["alpha_along"],
            "true_stretch": truth["alpha_across"] / truth["alpha_along"],
            "misfit_ratio": (found["anisotropic_misfit"] / found["isotropic_misfit"]
                             if found["isotropic_misfit"] > 0 else 1.0)}


def read_labels(path, size):
    """An 8-bit label image (brdfd's materials-mask.png: 0 off the part, then 1, 2, ...) as
    a list of ints; all 0 where the file is absent (the estimate found one material)."""
    if not os.path.exists(path):
        return [0] * size
    # PNGs are marked sRGB: kept so, the codes come back as they were written.
    b = mi.Bitmap(path).convert(mi.Bitmap.PixelFormat.Y, mi.Struct.Type.Float32,
                                srgb_gamma=True)
    return [round(v * 255.0) for v in mi.TensorXf(b).array]


def segmentation_iou(region, labels, regions):
    """Each true region's intersection over union with the estimate's material that matches
    it best, over the pixels wholly inside one region, under the one-to-one matching of
    regions to materials that maximises the smaller IoU: {region: IoU}."""
    found = sorted({labels[p] for p in region if labels[p] > 0})
    def iou(r, m):
        both = sum(1 for p, t in region.items() if t == r and labels[p] == m)
        either = sum(1 for p, t in region.items() if t == r or labels[p] == m)
        return both / either if either else 0.0
    best = {r: 0.0 for r in regions}
    if len(found) >= len(regions):
        import itertools
        for chosen in itertools.permutations(found, len(regions)):
            scores = {r: iou(r, m) for r, m in zip(regions, chosen)}
            if min(scores.values()) > min(best.values()):
                best = scores
    return best


def score_scene(maps, out, name, brdfd):
    d = os.path.join(out, name)
    with open(os.path.join(d, "scene.json")) as f:
        truth = json.load(f)
    ids, width = read_rgb(os.path.join(d, "regions.exr"))
    # A pixel wholly inside one region (its samples all on it): the edges mix part and
    # background, or two regions, differently in each renderer.
    region = {}
    for p in range(len(ids) // 3):
        v = ids[3 * p]
        r = round(v)
        if r > 0 and abs(v - r) < 1e-3:
            region[p] = r
    est = os.path.join(d, "estimate")
    run = subprocess.run([brdfd, "estimate", "--photo", os.path.join(d, "photo.exr"),
                          "--env", os.path.join(maps, CAPTURE + ".hdr"),
                          "--geometry", os.path.join(d, "geometry.toml"), "-o", est],
                         capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"{name}: brdfd estimate failed:\n{run.stderr}")
    with open(os.path.join(est, "coefficients.json")) as f:
        coefficients = json.load(f)
    result = {"scene": name, "breaks": truth["breaks"], "fit_error": coefficients["fit_error"],
              "summary": run.stdout, "per_map": {}, "per_region": {}}
    all_blocks = blocks(region, width, len(ids) // 3 // width)
    by_region = {r: [b for b in all_blocks if b[0] == r] for r in {b[0] for b in all_blocks}}
    if truth.get("photos_only"):
        raise SystemExit(f"{name}: rendered with --photos-only, it has no truths to score by")
    if not truth["held_out"]:
        raise SystemExit(f"{name}: no held-out map to relight under (MAPS held only {CAPTURE})")
    for m in truth["held_out"]:
        truth_path = os.path.join(d, f"truth-{m}.exr")
        if not os.path.exists(truth_path):
            raise SystemExit(f"{name}: {truth_path} is missing: the set was rendered with "
                             "--photos-only, or not finished; render it again")
        relit = os.path.join(est, f"relit-{m}.exr")
        run = subprocess.run([brdfd, "render", "--coefficients",
                              os.path.join(est, "coefficients.json"),
                              "--geometry", os.path.join(d, "geometry.toml"),
                              "--env", os.path.join(maps, m + ".hdr"), "--out", relit],
                             capture_output=True, text=True)
        if run.returncode != 0:
            raise SystemExit(f"{name}: brdfd render under {m} failed:\n{run.stderr}")
        ours, ours_width = read_rgb(relit)
        t, _ = read_rgb(truth_path)
        if (len(ours), ours_width) != (len(t), width):
            raise SystemExit(f"{name}: brdfd's render under {m} is not the truth's size")
        result["per_map"][m] = relative_rmse(ours, t, all_blocks)
        for r, kept in by_region.items():
            result["per_region"].setdefault(truth["regions"][str(r)], {})[m] = \
                relative_rmse(ours, t, kept)
        direct = os.path.join(d, f"direct-{m}.exr")
        if os.path.exists(direct):
            t, _ = read_rgb(direct)
            result.setdefault("per_map_against_direct", {})[m] = \
                relative_rmse(ours, t, all_blocks)
    errors = sorted(result["per_map"].values())
    result["relight_error"] = sum(errors) / len(errors)
    result["flags"] = [f["reason"] for f in coefficients.get("flags", [])]
    # Materials: how many the estimate found, and on a part of several, how its split
    # matches the truth's regions.
    split = coefficients.get("materials")
    result["materials_found"] = len(split["parts"]) if split else 1
    if len(truth["materials"]) > 1:
        labels = read_labels(os.path.join(est, "materials-mask.png"), len(ids) // 3)
        ious = segmentation_iou(region, labels, sorted(set(region.values())))
        result["segmentation_iou"] = {truth["regions"][str(r)]: v for r, v in ious.items()}
    found = coefficients.get("anisotropy")
    if "grain" in truth and found:
        result["grain"] = grain_error(truth["grain"], found)
    fit = result["fit_error"]
    fit = "n/a" if fit is None else f"{fit:.3f}"
    print(f"{name:20} fit {fit}  relight {result['relight_error']:.3f}  "
          + "  ".join(f"{m} {e:.3f}" for m, e in result["per_map"].items()), flush=True)
    for region_name, per in result["per_region"].items():
        if len(result["per_region"]) > 1:
            print(f"    {region_name:30} " + "  ".join(f"{m} {e:.3f}" for m, e in per.items()))
    if "per_map_against_direct" in result:
        print("    against direct light only      " + "  ".join(
            f"{m} {e:.3f}" for m, e in result["per_map_against_direct"].items()))
    if "grain" in result:
        print(f"    grain {result['grain']['degrees_off']:.1f}° off, stretch "
              f"{result['grain']['stretch']:.2f} (truth {result['grain']['true_stretch']:.2f})")
    if "segmentation_iou" in result:
        print("    materials found: " + str(result["materials_found"]) + ", IoU against the truth: "
              + "  ".join(f"{k} {v:.3f}" for k, v in result["segmentation_iou"].items()))
    elif result["materials_found"] > 1:
        print(f"    materials found: {result['materials_found']} (the truth has one)")
    print(f"    flagged: {', '.join(result['flags']) or 'no'}")
    return result


def main():
    if len(sys.argv) < 4 or sys.argv[1] not in ("render", "score") or (
            sys.argv[1] == "score" and len(sys.argv) < 5):
        raise SystemExit(__doc__)
    command, maps, out = sys.argv[1:4]
    rest = sys.argv[4:]
    if not os.path.exists(os.path.join(maps, CAPTURE + ".hdr")):
        raise SystemExit(f"{maps} holds no {CAPTURE}.hdr, the map the photos are taken under")
    # The LLVM variants need a libLLVM that a machine may lack or that may not compile
    # Mitsuba's kernels (Debian's LLVM 14 fails on them); the scalar one runs everywhere.
    mi.set_variant("scalar_rgb")
    if command == "render":
        spp, truths, names = 512, True, []
        while rest:
            a = rest.pop(0)
            if a == "--spp":
                if not rest or not rest[0].isdigit() or int(rest[0]) < 1:
                    raise SystemExit("--spp takes a number of samples per pixel, 1 or more")
                spp = int(rest.pop(0))
            elif a == "--photos-only":
                truths = False
            else:
                names.append(a)
        unknown = [n for n in names if n not in SCENES]
        if unknown:
            raise SystemExit(f"unknown scene {unknown[0]!r}: one of {', '.join(SCENES)}")
        for name in names or SCENES:
            render_scene(maps, out, name, spp, truths)
    else:
        brdfd, names = rest[0], rest[1:]
        unknown = [n for n in names if n not in SCENES]
        if unknown:
            raise SystemExit(f"unknown scene {unknown[0]!r}: one of {', '.join(SCENES)}")
        scores = [score_scene(maps, out, n, brdfd) for n in names or SCENES]
        with open(os.path.join(out, "scores.json"), "w") as f:
            json.dump(scores, f, indent=2)


if __name__ == "__main__":
    main()
