// The 3D view of a session's export: `material.gltf` loaded by three.js's glTF loader, lit by
// an environment map (the capture's light, or one of the four reference maps), turned by the
// mouse, beside the photo. Everything comes from the daemon: the library is compiled into it.
//
// The address says what to show: `?session=ID`, and optionally `shape=object` (the export on
// the session's mesh, where it has one), `map=NAME` (`capture` or a reference map), `turn=DEGREES` (the light about +Y), `background=off`, `camera=orthographic`
// (the view brdfd's own renders use: the unit sphere filling the frame, looking down −Z) and
// `exposure=X` (linear radiance × X is shown as white; otherwise from the map's mean).
//
// three.js draws the scene, but the sphere is shaded here rather than by its own materials:
// their image-based lighting (prefiltered maps, the split-sum approximation, diffuse from a
// blurred map) is 25–50% from the integral the export's BRDF defines, and this page exists to
// show what that BRDF looks like. The BRDF is glTF's (spec Appendix B) exactly as brdfd
// evaluates it (`GltfBrdf` in crates/report/src/export/gltf.rs), and the light is integrated as a path tracer
// would: the specular lobe by importance sampling with filtered lookups, the map's brightest
// texels as lights, the diffuse part from the map's cosine-convolved irradiance. Under the
// reference maps it is within 0.01–0.05 (relative RMSE) of `brdfd render --gltf`.
import * as THREE from "/vendor/three/three.module.min.js";
import { GLTFLoader } from "/vendor/three/GLTFLoader.js";
import { RGBELoader } from "/vendor/three/RGBELoader.js";
import { OrbitControls } from "/vendor/three/OrbitControls.js";

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const session = params.get("session");

// GGX samples per pixel. Each reads the map blurred to its share of the lobe's solid angle, so
// fewer samples give a smoother, slightly wider lobe rather than noise.
const SAMPLES = 128;
// The irradiance map's size: irradiance varies no faster than a cosine, so linear
// interpolation between 5.6° texels is within a fraction of a percent.
const IRRADIANCE_WIDTH = 64;
// The map is averaged to at most this width before it is convolved (an n² sum). The cosine
// kernel is smooth, so a sun spread over one such texel lights the same.
const CONVOLVE_WIDTH = 128;
// Steps of the table of the diffuse part's mean Fresnel loss against cos θo.
const FRESNEL_STEPS = 32;
// Lights taken from the map's brightest texels, and the width of the map they are taken at.
const PEAKS = 64;
const PEAK_WIDTH = 256;
// Half floats' largest value. Only the background clips a brighter sun: the lights hold it.
const HALF_MAX = 65504;

function showError(e) {
  $("error").textContent = String(e.message || e);
  $("error").hidden = false;
}

// A map's rows in brdfd's convention (crates/core/src/envmap.rs): row 0 looks up (+Y), column
// u faces azimuth φ = 2π(u − ½) from −Z towards +X. Solid angle of a texel of row y.
function rowSolidAngle(y, width, height) {
  return ((2 * Math.PI) / width) * (Math.cos((Math.PI * y) / height) - Math.cos((Math.PI * (y + 1)) / height));
}

// Averages an RGBA float image down to `w` × `h`, each texel weighted by its solid angle, so
// that every level of the chain holds the same power as the map.
function downsample(src, W, H, w, h) {
  const out = new Float32Array(w * h * 4);
  const weight = new Float64Array(w * h);
  const sum = new Float64Array(w * h * 3);
  for (let y = 0; y < H; y++) {
    const ty = Math.min(h - 1, Math.floor((y * h) / H));
    const dw = rowSolidAngle(y, W, H);
    for (let x = 0; x < W; x++) {
      const t = ty * w + Math.min(w - 1, Math.floor((x * w) / W));
      const i = (y * W + x) * 4;
      for (let c = 0; c < 3; c++) sum[t * 3 + c] += src[i + c] * dw;
      weight[t] += dw;
    }
  }
  for (let t = 0; t < w * h; t++) {
    for (let c = 0; c < 3; c++) out[t * 4 + c] = weight[t] > 0 ? sum[t * 3 + c] / weight[t] : 0;
    out[t * 4 + 3] = 1;
  }
  return out;
}

function toHalf(src) {
  const out = new Uint16Array(src.length);
  for (let i = 0; i < src.length; i++) out[i] = THREE.DataUtils.toHalfFloat(Math.min(src[i], HALF_MAX));
  return out;
}

function halfTexture(data, width, height, mipmaps) {
  const t = new THREE.DataTexture(toHalf(data), width, height, THREE.RGBAFormat, THREE.HalfFloatType);
  // Row 0 stays at t = 0: the shader's lookup follows brdfd's convention, not three.js's.
  t.flipY = false;
  t.wrapS = THREE.RepeatWrapping;
  t.wrapT = THREE.ClampToEdgeWrapping;
  t.magFilter = THREE.LinearFilter;
  if (mipmaps) {
    // Built here rather than by the GPU: generating them needs a renderable half-float format,
    // which WebGL2 does not promise, and this way each level is solid-angle weighted.
    t.mipmaps = mipmaps.map(([d, w, h]) => ({ data: toHalf(d), width: w, height: h }));
    t.generateMipmaps = false;
    t.minFilter = THREE.LinearMipmapLinearFilter;
  } else {
    t.minFilter = THREE.LinearFilter;
  }
  t.needsUpdate = true;
  return t;
}

function direction(x, y, width, height) {
  const theta = (Math.PI * (y + 0.5)) / height;
  const phi = 2 * Math.PI * ((x + 0.5) / width - 0.5);
  return [Math.sin(theta) * Math.sin(phi), Math.cos(theta), -Math.sin(theta) * Math.cos(phi)];
}

// E(n) = ∫ L(ω) max(0, n·ω) dω for each texel's direction n, summed over the map's texels:
// the exact Lambertian integral, where a 9-coefficient spherical-harmonic fit can be several
// percent off under a sun.
function irradiance(src, W, H) {
  const w = Math.min(W, CONVOLVE_WIDTH);
  const h = Math.max(1, Math.round((w * H) / W));
  const coarse = downsample(src, W, H, w, h);
  const n = w * h;
  const dirs = new Float64Array(n * 3);
  const power = new Float64Array(n * 3);
  for (let y = 0; y < h; y++) {
    const dw = rowSolidAngle(y, w, h);
    for (let x = 0; x < w; x++) {
      const i = y * w + x;
      dirs.set(direction(x, y, w, h), i * 3);
      for (let c = 0; c < 3; c++) power[i * 3 + c] = coarse[i * 4 + c] * dw;
    }
  }
  const ow = IRRADIANCE_WIDTH;
  const oh = ow / 2;
  const out = new Float32Array(ow * oh * 4);
  for (let y = 0; y < oh; y++) {
    for (let x = 0; x < ow; x++) {
      const [nx, ny, nz] = direction(x, y, ow, oh);
      let r = 0;
      let g = 0;
      let b = 0;
      for (let i = 0; i < n; i++) {
        const cos = nx * dirs[i * 3] + ny * dirs[i * 3 + 1] + nz * dirs[i * 3 + 2];
        if (cos > 0) {
          r += cos * power[i * 3];
          g += cos * power[i * 3 + 1];
          b += cos * power[i * 3 + 2];
        }
      }
      out.set([r, g, b, 1], (y * ow + x) * 4);
    }
  }
  return halfTexture(out, ow, oh, null);
}

// The brightest part of the map, as lights: a lamp or the sun holds much of a map's power in a
// few texels, which a fixed set of GGX samples would catch at some pixels and miss at others.
// The map is cut at the luminance of its (PEAKS + 1)-th brightest texel (at about 1.4° a
// texel), each of the PEAKS texels above gives its excess to a light in its direction, and
// the samples see the rest, whose range is then small enough to be smooth.
function peaks(rgba, W, H) {
  const pw = Math.min(W, PEAK_WIDTH);
  const ph = Math.max(1, Math.round((pw * H) / W));
  const coarse = downsample(rgba, W, H, pw, ph);
  const lum = new Float32Array(pw * ph);
  for (let i = 0; i < pw * ph; i++) {
    lum[i] = 0.2126 * coarse[i * 4] + 0.7152 * coarse[i * 4 + 1] + 0.0722 * coarse[i * 4 + 2];
  }
  const order = Array.from(lum.keys()).sort((i, j) => lum[j] - lum[i]);
  const cut = lum[order[Math.min(PEAKS, order.length - 1)]];
  const lights = new Float32Array(PEAKS * 4 * 2);
  const kept = new Float32Array(pw * ph).fill(1);
  for (let k = 0; k < Math.min(PEAKS, order.length); k++) {
    const i = order[k];
    if (!(lum[i] > cut)) break;
    kept[i] = cut / lum[i];
    const [x, y] = [i % pw, Math.floor(i / pw)];
    const dw = rowSolidAngle(y, pw, ph);
    // xyz: direction; w: the light's angular radius² / 8, by which it widens a GGX lobe's α²
    // (the disc's variance in half-vector slopes), as brdfd spreads its lights over a disc.
    lights.set([...direction(x, y, pw, ph), dw / Math.PI / 8], k * 8);
    for (let c = 0; c < 3; c++) lights[k * 8 + 4 + c] = coarse[i * 4 + c] * (1 - kept[i]) * dw;
  }
  // The fine texels under each light keep their pattern, scaled to the cut.
  const rest = rgba.slice();
  for (let y = 0; y < H; y++) {
    const ty = Math.min(ph - 1, Math.floor((y * ph) / H));
    for (let x = 0; x < W; x++) {
      const f = kept[ty * pw + Math.min(pw - 1, Math.floor((x * pw) / W))];
      if (f < 1) for (let c = 0; c < 3; c++) rest[(y * W + x) * 4 + c] *= f;
    }
  }
  return { lights, rest };
}

// The map as a texture with its mip chain (less its peaks, which come as lights), its
// irradiance, and its mean luminance (so that a white matte sphere shows mid-grey under any
// map).
function prepareMap(texture) {
  const { data, width: W, height: H } = texture.image;
  const channels = data.length / (W * H);
  const rgba = new Float32Array(W * H * 4);
  let sum = 0;
  for (let i = 0; i < W * H; i++) {
    for (let c = 0; c < 3; c++) rgba[i * 4 + c] = Math.max(0, data[i * channels + c]);
    rgba[i * 4 + 3] = 1;
    const y = Math.floor(i / W);
    sum += rowSolidAngle(y, W, H) * (0.2126 * rgba[i * 4] + 0.7152 * rgba[i * 4 + 1] + 0.0722 * rgba[i * 4 + 2]);
  }
  const { lights, rest } = peaks(rgba, W, H);
  const levels = [[rest, W, H]];
  while (levels.length < 16) {
    const [d, w, h] = levels[levels.length - 1];
    if (w === 1 && h === 1) break;
    const [nw, nh] = [Math.max(1, w >> 1), Math.max(1, h >> 1)];
    levels.push([downsample(d, w, h, nw, nh), nw, nh]);
  }
  return {
    env: halfTexture(rest, W, H, levels),
    background: halfTexture(rgba, W, H, null),
    // The diffuse part sees the whole map.
    irradiance: irradiance(rgba, W, H),
    lights,
    size: new THREE.Vector2(W, H),
    levels: levels.length,
    mean: sum / (4 * Math.PI),
  };
}

// For the diffuse part's Fresnel loss: the mean of Schlick's weight (1 − cos θd)⁵ over a
// cosine-weighted hemisphere of light directions, for a view at cos θo. The loss is small and
// smooth, so the map less its peaks is taken as even over it.
function fresnelMeans() {
  const table = new Float32Array(FRESNEL_STEPS);
  const K = 64;
  for (let s = 0; s < FRESNEL_STEPS; s++) {
    const mu = s / (FRESNEL_STEPS - 1);
    const wo = [Math.sqrt(1 - mu * mu), 0, mu];
    let sum = 0;
    // sin²θi uniform in [0, 1] and φ uniform: the cosine-weighted measure.
    for (let i = 0; i < K; i++) {
      const sin = Math.sqrt((i + 0.5) / K);
      const cos = Math.sqrt(1 - sin * sin);
      for (let j = 0; j < K; j++) {
        const phi = (2 * Math.PI * (j + 0.5)) / K;
        const dot = sin * Math.cos(phi) * wo[0] + cos * wo[2];
        const cosD = Math.sqrt(Math.max(0, (1 + dot) / 2));
        sum += (1 - cosD) ** 5;
      }
    }
    table[s] = sum / (K * K);
  }
  return table;
}

const COMMON = /* glsl */ `
  #define PI 3.141592653589793
  uniform float turn;
  // A world direction in the map's frame: the map is turned by \`turn\` about +Y, right-handed,
  // as brdfd's yaw turns it.
  vec3 toMap(vec3 d) {
    float c = cos(turn);
    float s = sin(turn);
    return vec3(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
  }
  // A direction's place in the map, in brdfd's convention.
  vec2 mapUv(vec3 d) {
    return vec2(atan(d.x, -d.z) / (2.0 * PI) + 0.5, acos(clamp(d.y, -1.0, 1.0)) / PI);
  }
`;

const SPHERE_VERTEX = /* glsl */ `
  varying vec3 vNormal;
  varying vec3 vPosition;
  #ifdef ANISOTROPIC
  // KHR_materials_anisotropy stretches the lobe along the mesh's tangent.
  attribute vec4 tangent;
  varying vec3 vTangent;
  #endif
  void main() {
    vec4 world = modelMatrix * vec4(position, 1.0);
    vPosition = world.xyz;
    vNormal = transpose(inverse(mat3(modelMatrix))) * normal;
    #ifdef ANISOTROPIC
    vTangent = mat3(modelMatrix) * tangent.xyz;
    #endif
    gl_Position = projectionMatrix * viewMatrix * world;
  }
`;

const SPHERE_FRAGMENT = /* glsl */ `
  ${COMMON}
  #define SAMPLES ${SAMPLES}
  #define FRESNEL_STEPS ${FRESNEL_STEPS}
  #define PEAKS ${PEAKS}
  uniform sampler2D envMap;
  uniform sampler2D irradianceMap;
  // Per light: direction and α² widening, then power (radiance × solid angle).
  uniform vec4 peaks[2 * PEAKS];
  uniform vec2 envSize;
  uniform float envLevels;
  uniform vec3 diffuseColor;
  // The specular factor, per channel, is specularA + specularB · (1 − cos θd)⁵.
  uniform vec3 specularA;
  uniform vec3 specularB;
  uniform float diffuseLossA;
  uniform float diffuseLossB;
  // GGX α along the lobe's tangent and across it (equal without KHR_materials_anisotropy),
  // and the turn of the tangent about the normal (anisotropyRotation).
  uniform vec2 alpha;
  uniform float anisotropyRotation;
  // KHR_materials_clearcoat: the coat's weight and GGX α.
  uniform float clearcoat;
  uniform float clearcoatAlpha;
  uniform float fresnelMean[FRESNEL_STEPS];
  varying vec3 vNormal;
  varying vec3 vPosition;
  #ifdef ANISOTROPIC
  varying vec3 vTangent;
  #endif

  float radicalInverse(uint b) {
    b = (b << 16u) | (b >> 16u);
    b = ((b & 0x55555555u) << 1u) | ((b & 0xAAAAAAAAu) >> 1u);
    b = ((b & 0x33333333u) << 2u) | ((b & 0xCCCCCCCCu) >> 2u);
    b = ((b & 0x0F0F0F0Fu) << 4u) | ((b & 0xF0F0F0F0u) >> 4u);
    b = ((b & 0x00FF00FFu) << 8u) | ((b & 0xFF00FF00u) >> 8u);
    return float(b) * 2.3283064365386963e-10;
  }

  // Smith's Λ for an anisotropic GGX of α (along t, along b), for a direction w in the
  // lobe's frame (t, b, n): brdfd's \`smith_lambda\` when the two are equal.
  float lambda(vec3 w, vec2 a) {
    float z2 = max(w.z * w.z, 1e-12);
    return 0.5 * (sqrt(1.0 + (a.x * a.x * w.x * w.x + a.y * a.y * w.y * w.y) / z2) - 1.0);
  }

  // Anisotropic GGX's D for a unit half vector in the lobe's frame: brdfd's \`ggx_d\` when
  // the two αs are equal.
  float ggx(vec3 h, vec2 a) {
    float k = h.x * h.x / (a.x * a.x) + h.y * h.y / (a.y * a.y) + h.z * h.z;
    return 1.0 / (PI * a.x * a.y * k * k);
  }

  // The map's light through one GGX lobe of roughness α (along t, along b): ∫ (A + B·w)·D·V·
  // cos θi·L dωi, with w = (1 − cos θd)⁵, at the pixel of normal n (tangents t, b) and view v.
  vec3 lobe(vec3 n, vec3 v, vec3 t, vec3 b, float nv, vec2 alpha, vec3 A, vec3 B) {
    vec3 ve = vec3(dot(v, t), dot(v, b), nv);
    float lv = lambda(ve, alpha);
    // Solid angle of a level-0 texel at the equator; a row's shrinks with sin θ.
    float texel = (2.0 * PI / envSize.x) * (PI / envSize.y);

    // Half vectors drawn from the visible normals (Heitz 2018, "Sampling the GGX Distribution
    // of Visible Normals"): pdf(l) = G₁(v)·D(h) / (4 cos θo), and f·cos/pdf = F·G₂/G₁(v),
    // bounded, so a fixed set of samples is an even quadrature of the lobe.
    vec3 vh = normalize(vec3(alpha * ve.xy, ve.z));
    float lensq = dot(vh.xy, vh.xy);
    vec3 t1 = lensq > 0.0 ? vec3(-vh.y, vh.x, 0.0) * inversesqrt(lensq) : vec3(1.0, 0.0, 0.0);
    vec3 t2 = cross(vh, t1);
    float stretch = 0.5 * (1.0 + vh.z);
    vec3 specular = vec3(0.0);
    for (int i = 0; i < SAMPLES; i++) {
      float r = sqrt((float(i) + 0.5) / float(SAMPLES));
      float phi = 2.0 * PI * radicalInverse(uint(i));
      float p1 = r * cos(phi);
      float p2 = mix(sqrt(1.0 - p1 * p1), r * sin(phi), stretch);
      vec3 nh = p1 * t1 + p2 * t2 + sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2)) * vh;
      vec3 hl = normalize(vec3(alpha * nh.xy, max(nh.z, 0.0)));
      vec3 h = t * hl.x + b * hl.y + n * hl.z;
      float cosD = dot(v, h);
      vec3 l = 2.0 * cosD * h - v;
      float nl = dot(n, l);
      if (nl <= 0.0) continue;
      float pdf = ggx(hl, alpha) / ((1.0 + lv) * 4.0 * nv);
      // Filtered importance sampling (Colbert & Křivánek, GPU Gems 3, ch. 20): the level
      // whose texels cover this sample's share of the lobe. The extra level of blur they
      // suggest would widen a rough lobe visibly (7% brighter on brdfd's fabric).
      float sinL = sqrt(max(1.0 - l.y * l.y, 1e-6));
      float lod = 0.5 * log2(1.0 / (float(SAMPLES) * pdf * texel * sinL));
      vec3 radiance = textureLod(envMap, mapUv(l), clamp(lod, 0.0, envLevels - 1.0)).rgb;
      float w = pow(1.0 - cosD, 5.0);
      float ll = lambda(vec3(dot(l, t), dot(l, b), nl), alpha);
      specular += radiance * (A + B * w) * (1.0 + lv) / (1.0 + lv + ll);
    }
    specular /= float(SAMPLES);

    // The lights: the BRDF at each one's direction, its lobe widened by the light's size.
    for (int i = 0; i < PEAKS; i++) {
      vec3 l = peaks[2 * i].xyz;
      float nl = dot(n, l);
      if (nl <= 0.0) continue;
      vec3 h = normalize(v + l);
      float w = pow(1.0 - max(dot(v, h), 0.0), 5.0);
      vec3 hl = vec3(dot(h, t), dot(h, b), max(dot(n, h), 0.0));
      float ll = lambda(vec3(dot(l, t), dot(l, b), nl), alpha);
      // D·V·cos θi, V's cos θi cancelled.
      float d = ggx(hl, sqrt(alpha * alpha + peaks[2 * i].w)) / ((1.0 + lv + ll) * 4.0 * nv);
      specular += peaks[2 * i + 1].rgb * (A + B * w) * d;
    }
    return specular;
  }

  void main() {
    // Shaded in the map's frame, where the lights are.
    vec3 n = toMap(normalize(vNormal));
    vec3 v = toMap(isOrthographic
      ? normalize(vec3(viewMatrix[0][2], viewMatrix[1][2], viewMatrix[2][2]))
      : normalize(cameraPosition - vPosition));
    // Where interpolated normals turn from the camera at the silhouette.
    float nv = max(dot(n, v), 1e-4);
    #ifdef ANISOTROPIC
    // The mesh's tangent laid on the shading normal, turned by anisotropyRotation.
    vec3 tm = toMap(vTangent);
    vec3 t0 = normalize(tm - n * dot(tm, n));
    vec3 t = cos(anisotropyRotation) * t0 + sin(anisotropyRotation) * cross(n, t0);
    #else
    vec3 t = normalize(cross(abs(n.y) < 0.999 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0), n));
    #endif
    vec3 b = cross(n, t);
    vec3 specular = lobe(n, v, t, b, nv, alpha, specularA, specularB);

    // The lights' share of the diffuse part's Fresnel loss is exact, the rest's is the mean.
    vec3 peakIrradiance = vec3(0.0);
    vec3 peakLoss = vec3(0.0);
    for (int i = 0; i < PEAKS; i++) {
      vec3 l = peaks[2 * i].xyz;
      float nl = dot(n, l);
      if (nl <= 0.0) continue;
      float w = pow(1.0 - max(dot(v, normalize(v + l)), 0.0), 5.0);
      vec3 power = peaks[2 * i + 1].rgb;
      peakIrradiance += power * nl;
      peakLoss += power * nl * w;
    }

    float f = nv * float(FRESNEL_STEPS - 1);
    int s = min(int(f), FRESNEL_STEPS - 2);
    float mean = mix(fresnelMean[s], fresnelMean[s + 1], f - float(s));
    vec3 irradiance = textureLod(irradianceMap, mapUv(n), 0.0).rgb;
    vec3 diffuse = diffuseColor / PI * ((1.0 - diffuseLossA) * irradiance
      - diffuseLossB * (mean * max(irradiance - peakIrradiance, 0.0) + peakLoss));

    // KHR_materials_clearcoat's fresnel_coat: the coat's lobe (no Fresnel of its own) mixed
    // over the base by its weight × Schlick's Fresnel of F₀ 0.04 at N·V.
    vec3 colour = diffuse + specular;
    if (clearcoat > 0.0) {
      float k = clearcoat * (0.04 + 0.96 * pow(1.0 - nv, 5.0));
      vec3 coat = lobe(n, v, t, b, nv, vec2(clearcoatAlpha), vec3(1.0), vec3(0.0));
      colour = mix(colour, coat, k);
    }
    gl_FragColor = vec4(colour, 1.0);
    #include <tonemapping_fragment>
    #include <colorspace_fragment>
  }
`;

// The map seen along each pixel's ray, for perspective and orthographic cameras alike. The
// ray's direction is affine across the screen, so the corners' directions interpolate.
const BACKGROUND_VERTEX = /* glsl */ `
  varying vec3 vDirection;
  void main() {
    mat4 back = inverse(projectionMatrix * viewMatrix);
    vec4 near = back * vec4(position.xy, -1.0, 1.0);
    vec4 far = back * vec4(position.xy, 1.0, 1.0);
    vDirection = far.xyz / far.w - near.xyz / near.w;
    gl_Position = vec4(position.xy, 1.0, 1.0);
  }
`;

const BACKGROUND_FRAGMENT = /* glsl */ `
  ${COMMON}
  uniform sampler2D backgroundMap;
  varying vec3 vDirection;
  void main() {
    gl_FragColor = vec4(textureLod(backgroundMap, mapUv(toMap(normalize(vDirection))), 0.0).rgb, 1.0);
    #include <tonemapping_fragment>
    #include <colorspace_fragment>
  }
`;

// The glTF BRDF's factors, from what the loader made of the material: base colour, metallic,
// roughness, and KHR_materials_specular, _ior, _clearcoat and _anisotropy where present
// (glTF's defaults otherwise).
// The mixes are folded here so that the shader evaluates
//   f = (1 − m)·(1 − s·max Fr)·c/π + [(1 − m)·s·Fr + m·(c + (1 − c)·w)]·D·V,
// Fr = F₀ + (1 − F₀)·w, F₀ = min(((η − 1)/(η + 1))² × specular colour, 1), w = (1 − cos θd)⁵,
// then mix(f, coat lobe, clearcoat × (0.04 + 0.96·(1 − N·V)⁵)), as `GltfBrdf::eval_angles`
// does.
function brdfUniforms(material, anisotropic) {
  const c = material.color ? material.color.toArray() : [1, 1, 1];
  const m = material.metalness ?? 1;
  const s = material.specularIntensity ?? 1;
  const sc = material.specularColor ? material.specularColor.toArray() : [1, 1, 1];
  const ior = material.ior ?? 1.5;
  const f0 = sc.map((k) => Math.min(((ior - 1) / (ior + 1)) ** 2 * k, 1));
  const f0max = Math.max(...f0);
  const a = (material.roughness ?? 1) ** 2;
  const strength = anisotropic ? material.anisotropy : 0;
  return {
    diffuseColor: { value: new THREE.Vector3(...c.map((k) => (1 - m) * k)) },
    specularA: { value: new THREE.Vector3(...c.map((k, i) => (1 - m) * s * f0[i] + m * k)) },
    specularB: { value: new THREE.Vector3(...c.map((k, i) => (1 - m) * s * (1 - f0[i]) + m * (1 - k))) },
    // max over channels of Fr is F₀max + (1 − F₀max)·w, since w ≤ 1.
    diffuseLossA: { value: s * f0max },
    diffuseLossB: { value: s * (1 - f0max) },
    // KHR_materials_anisotropy: α along the (turned) tangent is mix(α, 1, strength²).
    alpha: { value: new THREE.Vector2(Math.max(a + (1 - a) * strength ** 2, 1e-4), Math.max(a, 1e-4)) },
    anisotropyRotation: { value: material.anisotropyRotation ?? 0 },
    clearcoat: { value: material.clearcoat ?? 0 },
    clearcoatAlpha: { value: Math.max((material.clearcoatRoughness ?? 0) ** 2, 1e-4) },
  };
}

async function main() {
  if (!session) throw new Error("say which session: viewer.html?session=ID");
  const base = `/api/v1/sessions/${encodeURIComponent(session)}/result`;
  $("title").textContent = `session ${session}: 3D view`;
  // Whether there is a result to show, and the daemon's own words if not.
  const probe = await fetch(`${base}/coefficients.json`, { credentials: "same-origin" });
  if (probe.status === 401) throw new Error("sign in on the main page first (this daemon has a token)");
  if (!probe.ok) {
    const body = await probe.json().catch(() => ({}));
    throw new Error(body.message || `${probe.status} ${probe.statusText}`);
  }
  $("photo").src = `${base}/compare.png`;
  $("photo").addEventListener("error", () => ($("photo-figure").hidden = true));

  const canvas = $("view");
  const size = Number(params.get("size")) || canvas.width;
  canvas.width = canvas.height = size;
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(size, size, false);
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  // Linear: radiance × exposure, clipped at white, as brdfd's own previews show it.
  renderer.toneMapping = THREE.LinearToneMapping;
  renderer.debug.onShaderError = (gl, program, vertex, fragment) =>
    showError(`this browser cannot compile the viewer's shader: ${gl.getShaderInfoLog(fragment) || gl.getProgramInfoLog(program)}`);

  const orthographic = params.get("camera") === "orthographic";
  const camera = orthographic
    ? new THREE.OrthographicCamera(-1, 1, 1, -1, 0.1, 100)
    : new THREE.PerspectiveCamera(30, 1, 0.1, 100);
  camera.position.set(0, 0, orthographic ? 10 : 4.2);
  camera.lookAt(0, 0, 0);
  const scene = new THREE.Scene();
  const controls = new OrbitControls(camera, canvas);
  controls.enablePan = false;

  // Shared by every material, so that choosing or turning a map changes them all.
  const lighting = {
    envMap: { value: null },
    backgroundMap: { value: null },
    irradianceMap: { value: null },
    peaks: { value: new Float32Array(PEAKS * 8) },
    envSize: { value: new THREE.Vector2(1, 1) },
    envLevels: { value: 1 },
    turn: { value: 0 },
    fresnelMean: { value: fresnelMeans() },
  };

  // A glTF file's meshes, each shaded with its own material's BRDF.
  async function shaded(url) {
    const gltf = await new GLTFLoader().loadAsync(url);
    gltf.scene.traverse((o) => {
      if (!o.isMesh) return;
      // An anisotropic lobe is stretched along the mesh's tangents, which brdfd's exports
      // carry; a mesh without them is shaded isotropic (glTF would make them from its UVs,
      // and brdfd's meshes have none).
      const anisotropic = (o.material.anisotropy ?? 0) > 0 && !!o.geometry.attributes.tangent;
      o.material = new THREE.ShaderMaterial({
        uniforms: { ...lighting, ...brdfUniforms(o.material, anisotropic) },
        defines: anisotropic ? { ANISOTROPIC: "" } : {},
        vertexShader: SPHERE_VERTEX,
        fragmentShader: SPHERE_FRAGMENT,
      });
    });
    return gltf.scene;
  }
  const sphere = await shaded(`${base}/material.gltf`);
  scene.add(sphere);
  // On a mesh, the export on the object too (`object.gltf`), in the world the capture saw it
  // in, so that under the capture's light it is lit as it was at the bench. It is scaled to
  // the sphere's frame, not turned. Its own shadows and reflections on itself are not drawn.
  let object = null;
  const hasObject = (await fetch(`${base}/object.gltf`, { method: "HEAD", credentials: "same-origin" })).ok;
  $("shape-label").hidden = !hasObject;
  async function useShape() {
    const wantObject = hasObject && $("shape").value === "object";
    if (wantObject && !object) {
      object = await shaded(`${base}/object.gltf`);
      const bounds = new THREE.Box3().setFromObject(object).getBoundingSphere(new THREE.Sphere());
      const scale = 1 / Math.max(bounds.radius, 1e-9);
      object.scale.setScalar(scale);
      object.position.copy(bounds.center).multiplyScalar(-scale);
      scene.add(object);
    }
    sphere.visible = !wantObject;
    if (object) object.visible = wantObject;
    draw();
  }

  const background = new THREE.Mesh(
    new THREE.PlaneGeometry(2, 2),
    new THREE.ShaderMaterial({
      uniforms: { backgroundMap: lighting.backgroundMap, turn: lighting.turn },
      vertexShader: BACKGROUND_VERTEX,
      fragmentShader: BACKGROUND_FRAGMENT,
      depthTest: false,
      depthWrite: false,
    })
  );
  background.frustumCulled = false;
  background.renderOrder = -1;
  scene.add(background);

  const coefficients = await probe.json().catch(() => null);
  const exports = coefficients && coefficients.exports;
  if (exports && exports.relight_error != null) {
    $("verdict").textContent =
      `This export relights ${exports.relight_error.toFixed(3)} from the estimate ` +
      `(relative RMSE under maps it was not fitted to): ${exports.verdict}.`;
  }

  // The capture's light if the session has one, then the reference maps.
  const maps = [];
  const light = await fetch(`${base}/light.hdr`, { method: "HEAD", credentials: "same-origin" });
  if (light.ok) maps.push(["capture", `${base}/light.hdr`, "the capture's light"]);
  const references = await fetch("/maps").then((r) => r.json());
  for (const name of references) maps.push([name, `/maps/${name}.hdr`, name]);
  $("map").replaceChildren(
    ...maps.map(([name, , label]) => {
      const o = document.createElement("option");
      o.value = name;
      o.textContent = label;
      return o;
    })
  );
  const wanted = params.get("map");
  if (wanted && maps.some(([n]) => n === wanted)) $("map").value = wanted;
  if (params.get("background") === "off") $("background").checked = false;
  if (params.get("shape") === "object") $("shape").value = "object";
  $("turn").value = Number(params.get("turn")) || 0;

  // Frames are drawn when something changes: each costs SAMPLES map reads per pixel.
  let pending = false;
  // The shape is drawn before its map has loaded (unlit); only a frame under the map counts
  // as the first one.
  let lit = false;
  function draw() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      renderer.render(scene, camera);
      // For whoever waits on the first frame (the browser test).
      if (lit) document.body.dataset.rendered = "1";
    });
  }

  // Each map is loaded once, even when asked for again while it loads; the one shown is the
  // one selected when its load ends.
  const loaded = new Map();
  function load(name, url) {
    if (!loaded.has(name)) {
      loaded.set(
        name,
        new RGBELoader()
          .setDataType(THREE.FloatType)
          .loadAsync(url)
          .then((texture) => {
            const m = prepareMap(texture);
            texture.dispose();
            return m;
          })
      );
    }
    return loaded.get(name);
  }
  async function useMap() {
    const [name, url] = maps.find(([n]) => n === $("map").value);
    const m = await load(name, url);
    if ($("map").value !== name) return;
    lighting.envMap.value = m.env;
    lighting.backgroundMap.value = m.background;
    lighting.irradianceMap.value = m.irradiance;
    lighting.peaks.value = m.lights;
    lighting.envSize.value.copy(m.size);
    lighting.envLevels.value = m.levels;
    background.visible = $("background").checked;
    // A black map has no exposure of its own: it shows black at any.
    renderer.toneMappingExposure = Number(params.get("exposure")) || (m.mean > 0 ? 0.5 / m.mean : 1);
    lit = true;
    turn();
  }
  function turn() {
    const degrees = Number($("turn").value);
    $("turn-value").textContent = `${degrees}°`;
    lighting.turn.value = THREE.MathUtils.degToRad(degrees);
    draw();
  }
  $("map").addEventListener("change", () => useMap().catch(showError));
  $("background").addEventListener("change", () => useMap().catch(showError));
  $("turn").addEventListener("input", turn);
  $("shape").addEventListener("change", () => useShape().catch(showError));
  controls.addEventListener("change", draw);
  await useShape();
  await useMap();
}

main().catch(showError);
