// The page: loads the wasm engine (pkg/, built by .ci/web.sh), the bundled model and scene (assets/), renders
// view 0, then any camera the visitor orbits to. A file picker or a drop loads another model or scene (a scene
// file, or a frames folder: transforms.json and its images); a bad file shows its error and leaves the last good
// state in place. `window.app` is what the browser test drives.
import init, { Camera, Engine, SceneFile, SceneFolder } from './pkg/raypatch_web.js';

const BUNDLED_MODEL = 'assets/fitted_scene-2000000_rpsrt_k4.safetensors';
const BUNDLED_SCENE = 'assets/scene-2000000.safetensors';
const $ = (id) => document.getElementById(id);

const app = {
  engine: null, model: null, modelName: '', sceneFile: null, sceneName: '', scene: null,
  output: 'rgb', orbit: null, view: 0, intrinsics: null, wanted: false, busy: false,
  frameTimes: [], firstFrameMs: null, drawn: 0, ready: null,
};
window.app = app;

function showError(message) {
  $('error').textContent = message;
  $('error').hidden = false;
}

function clearError() {
  $('error').hidden = true;
  $('error').textContent = '';
}

function messageOf(e) {
  return e instanceof Error ? e.message : String(e);
}

async function fetchBytes(url) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return new Uint8Array(await response.arrayBuffer());
}

// ---- the camera: an orbit about the scene's centre, its up axis the world's ----

const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const scale = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => scale(a, 1 / Math.hypot(...a));

/** Two axes perpendicular to `up`, so that azimuth 0 lies along the first. */
function basis(up) {
  const helper = Math.abs(up[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
  const a = normalize(sub(helper, scale(up, dot(helper, up))));
  return [a, cross(up, a)];
}

/** The orbit through `eye` about `centre`. */
function orbitThrough(eye, centre, up) {
  const [a, b] = basis(up);
  const d = sub(eye, centre);
  const radius = Math.hypot(...d);
  return { centre, up, radius, azimuth: Math.atan2(dot(d, b), dot(d, a)), elevation: Math.asin(dot(d, up) / radius) };
}

/** The orbit's camera-to-world pose, 16 numbers row by row in OpenGL axes (as Camera.pinhole takes it). */
function orbitPose(o) {
  const [a, b] = basis(o.up);
  const flat = add(scale(a, Math.cos(o.azimuth)), scale(b, Math.sin(o.azimuth)));
  const dir = add(scale(flat, Math.cos(o.elevation)), scale(o.up, Math.sin(o.elevation)));
  const eye = add(o.centre, scale(dir, o.radius));
  const forward = normalize(sub(o.centre, eye));
  const right = normalize(cross(forward, o.up));
  const up = cross(right, forward);
  return [
    right[0], up[0], -forward[0], eye[0],
    right[1], up[1], -forward[1], eye[1],
    right[2], up[2], -forward[2], eye[2],
    0, 0, 0, 1,
  ];
}

function cameraOf(pose, [w, h, fx, fy, cx, cy]) {
  return Camera.pinhole(new Float64Array(pose), w, h, fx, fy, cx, cy);
}

// ---- loading ----

/** Makes `model` and `sceneFile` current once the scene is encoded; throws (changing nothing) if it cannot be. */
async function use(model, modelName, sceneFile, sceneName) {
  const scene = await model.encode(sceneFile);
  const view = scene.viewCamera(0);
  const [c0, c1, c2, u0, u1, u2] = scene.orbit();
  const old = [app.scene, app.model !== model && app.model, app.sceneFile !== sceneFile && app.sceneFile];
  Object.assign(app, { model, modelName, sceneFile, sceneName, scene, view: 0, intrinsics: view.slice(16) });
  app.orbit = orbitThrough([view[3], view[7], view[11]], [c0, c1, c2], [u0, u1, u2]);
  for (const o of old) if (o) o.free();
  $('model-name').textContent = `${modelName}: ${model.name}, ${model.outputs.join(', ')}`;
  $('precision').textContent = model.computesAs;
  $('scene-name').textContent = `${sceneName}: ${sceneFile.inputCount} input view(s), ${sceneFile.targetCount} target(s)`;
  const select = $('output');
  select.replaceChildren(...model.outputs.map((name) => new Option(name, name)));
  app.output = model.outputs.includes(app.output) ? app.output : 'rgb';
  select.value = app.output;
  app.firstFrameMs = null;
  requestFrame();
}

/** A scene from a frames folder `{name, files: {path inside it: bytes}}`. */
function folderScene({ name, files }) {
  const folder = new SceneFolder(name);
  try {
    for (const [path, bytes] of Object.entries(files)) folder.add(path, bytes);
    return SceneFile.fromFolder(folder);
  } finally {
    folder.free();
  }
}

/** Loads a model and/or a scene (`{name, bytes}` each; or a frames `folder`, see folderScene) and encodes the scene
 *  with the model, the current one for what is not given; on any error the last good model and scene stay. */
app.load = ({ model, scene, folder }, started = performance.now()) => exclusive(async () => {
  app.loadStart = started; // the first frame's time is counted from here
  const made = [];
  try {
    const m = model ? app.engine.loadModel(model.name, model.bytes) : app.model;
    if (model) made.push(m);
    const given = scene || folder;
    const s = scene ? SceneFile.fromBytes(scene.name, scene.bytes) : folder ? folderScene(folder) : app.sceneFile;
    if (given) made.push(s);
    await use(m, model ? model.name : app.modelName, s, given ? given.name : app.sceneName);
  } catch (e) {
    for (const object of made) object.free();
    throw e;
  }
});

/** Whether `bytes` are a scene file: a safetensors header that holds `input_images`. */
function isScene(bytes) {
  try {
    const length = Number(new DataView(bytes.buffer, bytes.byteOffset).getBigUint64(0, true));
    return 'input_images' in JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + length)));
  } catch {
    return false; // not a safetensors header: a .ckpt, or a bad file the model reader names
  }
}

/** Loads a frames folder `name` from `{path, file}` entries (File objects by their paths inside it). */
async function loadFolder(name, entries) {
  clearError();
  try {
    const files = {};
    for (const { path, file } of entries) files[path] = new Uint8Array(await file.arrayBuffer());
    await app.load({ folder: { name, files } });
  } catch (e) {
    showError(messageOf(e));
  }
}

/** Loads files as `kind` ('model', 'scene' or 'folder'), or each as what its content says (dropped files). A
 *  folder pick's files, and scene files among which is a transforms.json, are a frames folder: named by the first
 *  part of their paths (a folder pick's name), or `.` for files picked or dropped together. */
async function loadFiles(files, kind) {
  if (kind === 'folder' || (kind !== 'model' && files.some((f) => f.name === 'transforms.json'))) {
    if (!files.length) return;
    const parts = (f) => (f.webkitRelativePath || `./${f.name}`).split('/');
    await loadFolder(parts(files[0])[0], files.map((file) => ({ path: parts(file).slice(1).join('/'), file })));
    return;
  }
  for (const file of files) {
    clearError(); // what shows is the last file's outcome
    try {
      const bytes = new Uint8Array(await file.arrayBuffer());
      const as = kind || (isScene(bytes) ? 'scene' : 'model');
      await app.load({ [as]: { name: file.name, bytes } });
    } catch (e) {
      showError(messageOf(e));
    }
  }
}

// ---- rendering ----

/** Runs `work` with the engine to itself (it takes one request at a time). */
async function exclusive(work) {
  while (app.busy) await new Promise((resolve) => setTimeout(resolve, 1));
  app.busy = true;
  try {
    return await work();
  } finally {
    app.busy = false;
  }
}

/** Renders the current camera (target view `app.view`, or the orbit's) and draws it. */
async function renderAndDraw() {
  const started = performance.now();
  let rendered;
  if (app.view !== null) {
    rendered = await app.scene.renderView(app.view, [app.output]);
  } else {
    const camera = cameraOf(orbitPose(app.orbit), app.intrinsics);
    try {
      rendered = await app.scene.render(camera, [app.output]);
    } finally {
      camera.free();
    }
  }
  const [width, height] = [rendered.width, rendered.height];
  try {
    const canvas = $('view');
    [canvas.width, canvas.height] = [width, height];
    canvas.style.aspectRatio = `${width} / ${height}`;
    const pixels = new Uint8ClampedArray(rendered.rgba(app.output));
    canvas.getContext('2d').putImageData(new ImageData(pixels, width, height), 0, 0);
  } finally {
    rendered.free();
  }
  const now = performance.now();
  app.sinceNavigationMs ??= now; // the page's first frame, from navigation: wasm, adapter, downloads and all
  if (app.firstFrameMs === null) {
    app.firstFrameMs = now - app.loadStart;
    $('first-frame').textContent = `${app.firstFrameMs.toFixed(0)} ms (load, encode, first render)`;
  }
  app.frameTimes.push(now - started);
  if (app.frameTimes.length > 30) app.frameTimes.shift();
  const mean = app.frameTimes.reduce((s, t) => s + t, 0) / app.frameTimes.length;
  $('fps').textContent = `${(1000 / mean).toFixed(1)} fps (${mean.toFixed(1)} ms a frame, ${width}x${height})`;
  app.drawn += 1;
}

/** Asks for a frame; frames are rendered one at a time, the newest camera when the last one is done. */
function requestFrame() {
  if (app.wanted) return;
  app.wanted = true;
  requestAnimationFrame(async () => {
    app.wanted = false;
    if (!app.scene) return;
    try {
      await exclusive(renderAndDraw);
    } catch (e) {
      showError(messageOf(e));
    }
  });
}

/** The camera the test asks for: null for a target view (a number), a motion's frame `{motion, frames, index}`, or a
 *  pinhole `{pose, intrinsics}`. */
function askedCamera(camera) {
  if (typeof camera === 'number') return null;
  if (camera.motion) return app.scene.motionCamera(camera.motion, camera.frames, camera.index);
  return cameraOf(camera.pose, camera.intrinsics);
}

/** The floats of `outputs` for target view `view`, or for a camera (see askedCamera) (for the test). */
app.floats = (camera, outputs) => exclusive(async () => {
  const made = askedCamera(camera);
  try {
    const rendered = made ? await app.scene.render(made, outputs) : await app.scene.renderView(camera, outputs);
    try {
      return Object.fromEntries(outputs.map((o) => [o, Array.from(rendered.floats(o))]));
    } finally {
      rendered.free();
    }
  } finally {
    if (made) made.free();
  }
});

/** The pose of the current orbit turned by `azimuth` and `elevation` radians, with its intrinsics. */
app.orbitCamera = (azimuth = 0, elevation = 0) => ({
  pose: orbitPose({ ...app.orbit, azimuth: app.orbit.azimuth + azimuth, elevation: app.orbit.elevation + elevation }),
  intrinsics: app.intrinsics,
});

/** Milliseconds a frame takes, the median of `count` renders one after another: of target view `camera`, or of a
 *  camera (see askedCamera). */
app.frameMs = (camera, count) => exclusive(async () => {
  const made = askedCamera(camera);
  const times = [];
  try {
    for (let i = 0; i < count; i++) {
      await new Promise(requestAnimationFrame); // as the page's frames are asked for
      const started = performance.now();
      (await (made ? app.scene.render(made, [app.output]) : app.scene.renderView(camera, [app.output]))).free();
      times.push(performance.now() - started);
    }
  } finally {
    if (made) made.free();
  }
  return times.sort((a, b) => a - b)[count >> 1];
});

// ---- dropped folders ----

const entryFile = (entry) => new Promise((resolve, reject) => entry.file(resolve, reject));

/** The files under a dropped folder's entry, `{path, file}` with the path inside the folder. */
async function folderFiles(folder, prefix = '') {
  const found = [];
  const reader = folder.createReader();
  for (;;) {
    const batch = await new Promise((resolve, reject) => reader.readEntries(resolve, reject));
    if (!batch.length) return found;
    for (const entry of batch) {
      if (entry.isDirectory) found.push(...await folderFiles(entry, `${prefix}${entry.name}/`));
      else found.push({ path: `${prefix}${entry.name}`, file: await entryFile(entry) });
    }
  }
}

// ---- moving: mouse, touch, keys ----

function move(dAzimuth, dElevation, zoom = 1) {
  if (!app.orbit) return;
  const o = app.orbit;
  o.azimuth += dAzimuth;
  o.elevation = Math.max(-1.5, Math.min(1.5, o.elevation + dElevation));
  o.radius = Math.max(0.1, o.radius * zoom);
  app.view = null;
  requestFrame();
}

function controls() {
  const canvas = $('view');
  const pointers = new Map();
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
  });
  canvas.addEventListener('pointermove', (e) => {
    const last = pointers.get(e.pointerId);
    if (!last) return;
    const [dx, dy] = [e.clientX - last[0], e.clientY - last[1]];
    if (pointers.size === 2) {
      // Pinch: the distance between the two fingers before and after this one moved.
      const other = [...pointers.entries()].find(([id]) => id !== e.pointerId)[1];
      const before = Math.hypot(last[0] - other[0], last[1] - other[1]);
      const after = Math.hypot(e.clientX - other[0], e.clientY - other[1]);
      if (before > 0 && after > 0) move(0, 0, before / after);
    } else {
      move(-dx * 0.01, dy * 0.01);
    }
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
  });
  const release = (e) => pointers.delete(e.pointerId);
  canvas.addEventListener('pointerup', release);
  canvas.addEventListener('pointercancel', release);
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    move(0, 0, Math.exp(e.deltaY * 0.001));
  }, { passive: false });
  canvas.addEventListener('keydown', (e) => {
    const step = 0.05;
    const keys = {
      ArrowLeft: [step, 0], ArrowRight: [-step, 0], ArrowUp: [0, step], ArrowDown: [0, -step],
      a: [step, 0], d: [-step, 0], w: [0, 0, 0.95], s: [0, 0, 1 / 0.95],
    };
    const k = keys[e.key];
    if (!k) return;
    e.preventDefault();
    move(...k);
  });
  $('output').addEventListener('change', (e) => {
    app.output = e.target.value;
    requestFrame();
  });
  $('reset').addEventListener('click', () => {
    if (!app.scene) return;
    app.view = 0;
    const view = app.scene.viewCamera(0);
    app.orbit = orbitThrough([view[3], view[7], view[11]], app.orbit.centre, app.orbit.up);
    requestFrame();
  });
  for (const [input, kind] of [['model-file', 'model'], ['scene-file', 'scene'], ['folder-file', 'folder']]) {
    $(input).addEventListener('change', async (e) => {
      await loadFiles([...e.target.files], kind);
      e.target.value = '';
    });
  }
  document.addEventListener('dragover', (e) => {
    e.preventDefault();
    document.body.classList.add('dragging');
  });
  document.addEventListener('dragleave', (e) => {
    if (e.relatedTarget === null) document.body.classList.remove('dragging');
  });
  document.addEventListener('drop', async (e) => {
    e.preventDefault();
    document.body.classList.remove('dragging');
    // The entries must be taken now: the drop's items are gone once this handler awaits.
    const entries = [...e.dataTransfer.items].map((item) => item.webkitGetAsEntry?.()).filter(Boolean);
    const folders = entries.filter((entry) => entry.isDirectory);
    const files = folders.length ? await Promise.all(entries.filter((entry) => entry.isFile).map(entryFile))
      : [...e.dataTransfer.files];
    if (files.length) await loadFiles(files);
    for (const folder of folders) await loadFolder(folder.name, await folderFiles(folder));
  });
}

async function main() {
  if (!navigator.gpu) {
    $('no-webgpu').hidden = false;
    $('adapter').textContent = 'no WebGPU';
    return;
  }
  await init();
  try {
    app.engine = await Engine.create();
  } catch (e) {
    $('no-webgpu').hidden = false;
    $('adapter').textContent = messageOf(e);
    return;
  }
  $('adapter').textContent = app.engine.adapter;
  controls();
  const fetched = performance.now();
  const [model, scene] = await Promise.all([BUNDLED_MODEL, BUNDLED_SCENE].map(async (url) => {
    return { name: url.split('/').pop(), bytes: await fetchBytes(url) };
  }));
  await app.load({ model, scene }, fetched); // the first frame's time counts the download too
}

app.ready = main().catch((e) => showError(messageOf(e)));
