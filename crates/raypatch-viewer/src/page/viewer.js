// The raypatch viewer page: a camera flown with the mouse and keys, rendered by GET /render.png.
// Poses are 4x4 camera-to-world matrices, row-major, OpenGL axes (NeRF's transform_matrix); the world is z-up.
'use strict';

const SETTLE_MS = 250;       // after this long without camera moves, the full size is rendered
const MAX_IN_FLIGHT = 4;     // two rendering (the server's two render threads), one waiting, one replacing it
const MIN_SEND_MS = 20;      // at most 50 requests a second: under the server's 60 per client
const UP = [0, 0, 1];

const $ = (id) => document.getElementById(id);
const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const scale = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
const norm = (a) => scale(a, 1 / Math.hypot(...a));
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];

const view = {
  info: null,
  model: 0,
  scene: 0,
  output: 'rgb',
  eye: [0, 0, 1],
  center: [0, 0, 0],
  exactPose: null,   // a camera jumped to, rendered as given until the next move
  lastMove: -Infinity,
  dirty: false,
  inFlight: 0,
  sent: 0,           // sequence number of the last request
  sentAt: -Infinity,
  sendTimer: null,
  shown: 0,          // sequence number of the frame on screen
  frameTimes: [],
  client: Array.from(crypto.getRandomValues(new Uint8Array(12)), (b) => b.toString(16).padStart(2, '0')).join(''),
};

// The page's state, for scripts and the browser test (tests/browser): `viewer.sent` numbers the newest request.
window.viewer = view;

/** The pose looking from the eye at the orbit centre with z up. */
function lookAtPose(eye, center) {
  const f = norm(sub(center, eye));
  let r = cross(f, UP);
  r = Math.hypot(...r) < 1e-9 ? [1, 0, 0] : norm(r);
  const u = cross(r, f);
  return [r[0], u[0], -f[0], eye[0], r[1], u[1], -f[1], eye[1], r[2], u[2], -f[2], eye[2], 0, 0, 0, 1];
}

function currentPose() {
  return view.exactPose || lookAtPose(view.eye, view.center);
}

/** Jumps to a camera: renders its pose as given, orbiting from then on about the point of its forward ray
 *  nearest the world origin. */
function jumpTo(pose) {
  const eye = [pose[3], pose[7], pose[11]];
  const forward = [-pose[2], -pose[6], -pose[10]];
  let t = dot(scale(eye, -1), forward);
  if (!(t > 1e-3)) t = Math.max(Math.hypot(...eye), 1);
  view.eye = eye;
  view.center = add(eye, scale(forward, t));
  view.exactPose = pose.slice();
  changed(false);
}

/** Marks the camera (or what is shown) changed; `moving` asks for the quick preview size. */
function changed(moving) {
  if (moving) {
    view.exactPose = null;
    view.lastMove = performance.now();
    clearTimeout(view.settle);
    view.settle = setTimeout(() => { view.dirty = true; pump(); }, SETTLE_MS);
  }
  view.dirty = true;
  pump();
}

/** Full size: the scene's, a size the model renders (the server's `sizes`). */
function fullSize() {
  return view.info.scenes[view.scene].sizes[view.model];
}

/** While moving: about half the full size, a size the model renders (the server's `preview_sizes`). */
function previewSize() {
  return view.info.scenes[view.scene].preview_sizes[view.model];
}

/** Sends the newest camera when one is wanted; older requests still waiting on the server are replaced. */
function pump() {
  if (!view.info || !view.dirty || view.inFlight >= MAX_IN_FLIGHT || view.sendTimer) return;
  const wait = view.sentAt + MIN_SEND_MS - performance.now();
  if (wait > 0) {
    view.sendTimer = setTimeout(() => { view.sendTimer = null; pump(); }, wait);
    return;
  }
  view.dirty = false;
  view.sentAt = performance.now();
  const moving = performance.now() - view.lastMove < SETTLE_MS;
  const [w, h] = moving ? previewSize() : fullSize();
  const pose = currentPose();
  const params = new URLSearchParams({
    pose: pose.map((v) => +v.toPrecision(12)).join(','),
    size: `${w}x${h}`, model: view.model, scene: view.scene, output: view.output, client: view.client,
  });
  const seq = ++view.sent;
  view.inFlight++;
  fetch(`/render.png?${params}`)
    .then(async (response) => {
      if (response.status === 409) return;  // replaced by a newer camera
      if (!response.ok) throw new Error(await response.text());
      const blob = await response.blob();
      if (seq > view.shown) show(seq, blob, response.headers.get('X-Render-Ms'), params, w, h);
    })
    .catch((e) => showError(e.message))
    .finally(() => { view.inFlight--; pump(); });
}

function show(seq, blob, renderMs, params, w, h) {
  view.shown = seq;
  const img = $('view');
  const old = img.src;
  img.onload = () => {
    // An integer multiple of the full size fills the stage; a preview frame is stretched to the same box.
    const stage = $('stage'), [fw, fh] = fullSize();
    const zoom = Math.max(1, Math.floor(Math.min(stage.clientWidth / fw, stage.clientHeight / fh))) * fw / w;
    img.style.width = `${img.naturalWidth * zoom}px`;
    img.style.height = `${img.naturalHeight * zoom}px`;
    if (old) URL.revokeObjectURL(old);
  };
  img.dataset.pose = params.get('pose');
  img.dataset.size = `${w}x${h}`;
  img.dataset.output = params.get('output');
  img.dataset.model = params.get('model');
  img.dataset.frame = String(seq);
  img.src = URL.createObjectURL(blob);
  const now = performance.now();
  view.frameTimes = view.frameTimes.filter((t) => now - t < 1000).concat([now]);
  const m = view.info.models[view.model];
  $('stats').textContent = `${m.name} (${m.family}, k=${m.k}; ${m.computes}) on ${view.info.adapter} · ${w}x${h} · ` +
    `render ${(+renderMs).toFixed(1)} ms · ${view.frameTimes.length} fps`;
  $('error').classList.remove('shown');
}

function showError(message) {
  $('error').textContent = message;
  $('error').classList.add('shown');
}

function fillSelect(select, names, chosen) {
  select.replaceChildren(...names.map((name, i) => new Option(name, String(i), false, i === chosen)));
}

function fillOutputs() {
  const outputs = view.info.models[view.model].outputs;
  if (!outputs.includes(view.output)) view.output = 'rgb';
  $('output').replaceChildren(...outputs.map((o) => new Option(o, o, false, o === view.output)));
}

function fillCameras() {
  const scene = view.info.scenes[view.scene];
  $('inputs').replaceChildren(...scene.inputs.map((camera, i) => {
    const button = document.createElement('button');
    button.title = `input view ${i}`;
    button.disabled = !camera.pose;
    const thumb = new Image();
    thumb.src = `/input.png?scene=${view.scene}&view=${i}`;
    thumb.alt = `input view ${i}`;
    button.append(thumb);
    button.onclick = () => jumpTo(camera.pose);
    return button;
  }));
  $('targets').replaceChildren(...scene.targets.map((camera, i) => {
    const button = document.createElement('button');
    button.textContent = `target ${i}`;
    button.disabled = !camera.pose;
    button.onclick = () => jumpTo(camera.pose);
    return button;
  }));
}

function orbit(azimuth, elevation) {
  const offset = sub(view.eye, view.center);
  const radius = Math.hypot(...offset);
  const a = Math.atan2(offset[1], offset[0]) + azimuth;
  const limit = Math.PI / 2 - 0.05;
  const e = Math.min(limit, Math.max(-limit, Math.asin(offset[2] / radius) + elevation));
  view.eye = add(view.center, scale([Math.cos(e) * Math.cos(a), Math.cos(e) * Math.sin(a), Math.sin(e)], radius));
  changed(true);
}

function zoom(factor) {
  const offset = sub(view.eye, view.center);
  const radius = Math.min(1e3, Math.max(1e-2, Math.hypot(...offset) * factor));
  view.eye = add(view.center, scale(norm(offset), radius));
  changed(true);
}

/** Moves eye and centre together, along the view's forward, right and the world's up. */
function move(forward, right, up) {
  const f = norm(sub(view.center, view.eye));
  const r = norm(cross(f, UP));
  const step = 0.05 * Math.hypot(...sub(view.eye, view.center));
  const d = add(add(scale(f, forward * step), scale(r, right * step)), scale(UP, up * step));
  view.eye = add(view.eye, d);
  view.center = add(view.center, d);
  changed(true);
}

function bindControls() {
  const stage = $('stage');
  let drag = null;
  stage.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; stage.setPointerCapture(e.pointerId); stage.focus(); });
  stage.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const [dx, dy] = [e.clientX - drag[0], e.clientY - drag[1]];
    drag = [e.clientX, e.clientY];
    orbit(-dx * 0.01, dy * 0.01);
  });
  stage.addEventListener('pointerup', () => { drag = null; });
  stage.addEventListener('wheel', (e) => { e.preventDefault(); zoom(Math.exp(e.deltaY * 0.001)); }, { passive: false });
  const keys = {
    w: () => move(1, 0, 0), s: () => move(-1, 0, 0), a: () => move(0, -1, 0), d: () => move(0, 1, 0),
    q: () => move(0, 0, -1), e: () => move(0, 0, 1),
    ArrowLeft: () => orbit(0.08, 0), ArrowRight: () => orbit(-0.08, 0),
    ArrowUp: () => orbit(0, 0.08), ArrowDown: () => orbit(0, -0.08),
  };
  window.addEventListener('keydown', (e) => {
    const action = keys[e.key.length === 1 ? e.key.toLowerCase() : e.key];
    if (action && e.target.tagName !== 'SELECT') { e.preventDefault(); action(); }
  });
  $('model').onchange = (e) => { view.model = +e.target.value; fillOutputs(); changed(false); };
  $('scene').onchange = (e) => { view.scene = +e.target.value; fillCameras(); startAt(view.info.scenes[view.scene]); };
  $('output').onchange = (e) => { view.output = e.target.value; changed(false); };
}

function startAt(scene) {
  const first = scene.pose || scene.targets.concat(scene.inputs).map((c) => c.pose).find(Boolean);
  if (first) jumpTo(first); else showError('this scene has no posed camera to start from');
}

async function main() {
  const response = await fetch('/api/info');
  if (!response.ok) throw new Error(await response.text());
  view.info = await response.json();
  fillSelect($('model'), view.info.models.map((m) => `${m.name} (${m.family}, k=${m.k})`), 0);
  fillSelect($('scene'), view.info.scenes.map((s) => s.name), 0);
  fillOutputs();
  fillCameras();
  bindControls();
  startAt(view.info.scenes[0]);
}

main().catch((e) => showError(`cannot start the viewer: ${e.message}`));
