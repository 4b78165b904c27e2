"""Reference renders by Mitsuba 3 (PyPI `mitsuba`), a renderer no one here wrote, of what
`brdfd render --gltf` renders: a unit sphere under an environment map, seen by an orthographic
camera looking down -Z that spans 2 world units (brdfd's built-in sphere).

    python mitsuba-reference.py MAP.hdr SIZE OUT_DIR CASE...

Each CASE is `diffuse` (Lambert, albedo 0.5) or `mirror-ALPHA` (a GGX conductor whose
Fresnel is 1, roughness alpha = ALPHA): the glTF materials base colour 0.5 with no specular,
and metallic 1 with base colour 1. Each writes OUT_DIR/CASE.exr, linear radiance.

Orientation: Mitsuba's envmap puts the image's middle column at +Z, brdfd at -Z
(docs/formats.md), so the map is turned half a turn about +Y. Mitsuba's GGX shadows with the
separable Smith term, glTF's BRDF with the height-correlated one; they differ by a few percent
near the silhouette.
"""

import sys

import mitsuba as mi

mi.set_variant("scalar_rgb")


def bsdf(case):
    """The case's BSDF, and how to sample it: (samples per pixel, light samples, BSDF
    samples). A matte surface converges by sampling the map, a mirror by sampling both; at
    these counts Mitsuba's own noise is about 0.04 in the figure (relative RMSE of two seeds)."""
    if case == "diffuse":
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}, (256, 8, 1)
    if case.startswith("mirror-"):
        return {
            "type": "roughconductor",
            "material": "none",
            "distribution": "ggx",
            "alpha": float(case[len("mirror-"):]),
        }, (128, 4, 4)
    raise SystemExit(f"unknown case {case!r}: diffuse or mirror-ALPHA")


def main():
    env, size, out, cases = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:]
    for case in cases:
        material, (spp, light_samples, bsdf_samples) = bsdf(case)
        scene = mi.load_dict({
            "type": "scene",
            # Direct light only, as brdfd renders a convex sphere; both light and BSDF are
            # sampled (multiple importance), so a mirror and a matte surface converge alike.
            "integrator": {"type": "direct", "emitter_samples": light_samples,
                           "bsdf_samples": bsdf_samples},
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": size, "height": size,
                         "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": spp},
            },
            "light": {"type": "envmap", "filename": env,
                      "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 180)},
            "sphere": {"type": "sphere", "bsdf": material},
        })
        image = mi.TensorXf(mi.render(scene))
        mi.Bitmap(image).write(f"{out}/{case}.exr")


if __name__ == "__main__":
    main()
