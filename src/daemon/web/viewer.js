// The 3D view of a session's export: `material.gltf` loaded by three.js's glTF loader, lit by
// an environment map (the capture's light, or one of the four reference maps), turned by the
// mouse, beside the photo. Everything comes from the daemon: the library is compiled into it.
//
// The address says what to show: `?session=ID`, and optionally `map=NAME` (`capture` or a
// reference map), `turn=DEGREES` (the light about +Y), `background=off`, `camera=orthographic`
// (the view brdfd's own renders use: the unit sphere filling the frame, looking down −Z) and
// `exposure=X` (linear radiance × X is shown as white; otherwise from the map's mean).
import * as THREE from "/vendor/three/three.module.min.js";
import { GLTFLoader } from "/vendor/three/GLTFLoader.js";
import { RGBELoader } from "/vendor/three/RGBELoader.js";
import { OrbitControls } from "/vendor/three/OrbitControls.js";

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const session = params.get("session");

// brdfd's maps put −Z at the middle column and +X three quarters across (docs/formats.md);
// three.js's equirectangular lookup puts −Z a quarter across. A quarter turn about +Y takes one
// to the other.
const MAP_TURN = Math.PI / 2;

function showError(e) {
  $("error").textContent = String(e.message || e);
  $("error").hidden = false;
}

// The map's mean luminance, so that a white matte sphere shows mid-grey under any map.
function meanLuminance(texture) {
  const { data, width, height } = texture.image;
  const channels = data.length / (width * height);
  let sum = 0;
  let weight = 0;
  for (let y = 0; y < height; y++) {
    // Rows near the poles cover less of the sphere.
    const w = Math.sin((Math.PI * (y + 0.5)) / height);
    for (let x = 0; x < width; x++) {
      const i = (y * width + x) * channels;
      const v = (c) => (data instanceof Uint16Array ? THREE.DataUtils.fromHalfFloat(data[i + c]) : data[i + c]);
      sum += w * (0.2126 * v(0) + 0.7152 * v(1) + 0.0722 * v(2));
      weight += w;
    }
  }
  return sum / weight;
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

  const orthographic = params.get("camera") === "orthographic";
  const camera = orthographic
    ? new THREE.OrthographicCamera(-1, 1, 1, -1, 0.1, 100)
    : new THREE.PerspectiveCamera(30, 1, 0.1, 100);
  camera.position.set(0, 0, orthographic ? 10 : 4.2);
  camera.lookAt(0, 0, 0);
  const scene = new THREE.Scene();
  const controls = new OrbitControls(camera, canvas);
  controls.enablePan = false;

  const gltf = await new GLTFLoader().loadAsync(`${base}/material.gltf`);
  scene.add(gltf.scene);

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
  $("turn").value = Number(params.get("turn")) || 0;

  const pmrem = new THREE.PMREMGenerator(renderer);
  // Each map is loaded once, even when asked for again while it loads; the one shown is the
  // one selected when its load ends.
  const loaded = new Map();
  function load(name, url) {
    if (!loaded.has(name)) {
      loaded.set(
        name,
        new RGBELoader().loadAsync(url).then((texture) => {
          texture.mapping = THREE.EquirectangularReflectionMapping;
          const env = pmrem.fromEquirectangular(texture).texture;
          return { texture, env, mean: meanLuminance(texture) };
        })
      );
    }
    return loaded.get(name);
  }
  async function useMap() {
    const [name, url] = maps.find(([n]) => n === $("map").value);
    const m = await load(name, url);
    if ($("map").value !== name) return;
    scene.environment = m.env;
    scene.background = $("background").checked ? m.texture : null;
    // A black map has no exposure of its own: it shows black at any.
    renderer.toneMappingExposure = Number(params.get("exposure")) || (m.mean > 0 ? 0.5 / m.mean : 1);
    turn();
  }
  function turn() {
    const degrees = Number($("turn").value);
    $("turn-value").textContent = `${degrees}°`;
    const y = MAP_TURN + THREE.MathUtils.degToRad(degrees);
    scene.environmentRotation.set(0, y, 0);
    scene.backgroundRotation.set(0, y, 0);
  }
  $("map").addEventListener("change", () => useMap().catch(showError));
  $("background").addEventListener("change", () => useMap().catch(showError));
  $("turn").addEventListener("input", turn);
  await useMap();

  renderer.setAnimationLoop(() => {
    controls.update();
    renderer.render(scene, camera);
    // For whoever waits on the first frame (the browser test).
    document.body.dataset.rendered = "1";
  });
}

main().catch(showError);
