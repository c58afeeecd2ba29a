// The engine in the browser (web/, built into target/web by .ci/web.sh): headless Chromium (Debian's package, WebGPU
// on SwiftShader) driven by Playwright opens the page, waits for the bundled scene's first frame, and compares the
// page's floats with native `render-frame --out-raw` for the same cameras: the bundled scene's view 0 and two orbit
// cameras, frame 3 of a 12-frame orbit motion, and view 0 of every golden case (assets/golden, every family), each
// within MAX_ABS; then a frames folder (transforms.json and PNGs) made of the bundled scene's target views, picked
// as a folder, against render-frame reading the same folder, and a second model picked from a file (rpsrt_k2) on
// the bundled scene. A corrupt model, a corrupt scene and a corrupt
// transforms.json, loaded through the page's file pickers, must show render-frame's message for them, and a drag
// must render after them. A screenshot (target/web/screenshot.png) must not be blank; without WebGPU the page must
// say so. Ends with `web: N passed, M failed`.
//
//   node web.test.mjs   (from tests/browser, after `npm ci`, `cargo build --release -p raypatch-cli` and the page's
//                        build into target/web)
//
// RENDER_FRAME, CHROMIUM (default /usr/bin/chromium) and WEB_DIR (default ../../target/web) change where things are.
import { spawnSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '../..');
const renderFrame = process.env.RENDER_FRAME || path.join(root, 'target/release/render-frame');
const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
const webDir = process.env.WEB_DIR || path.join(root, 'target/web');
const goldenDir = path.join(root, 'assets/golden');
const bundledModel = path.join(root, 'assets/models/fitted_scene-2000000_rpsrt_k4.safetensors');
const bundledScene = path.join(root, 'assets/scenes/scene-2000000.safetensors');
const MAX_ABS = 1e-4;
const WAIT_MS = 300_000;
const work = fs.mkdtempSync(path.join(os.tmpdir(), 'raypatch-web-'));

const results = [];
function record(name, ok, detail) {
  results.push(ok);
  console.log(`${ok ? 'ok' : 'FAILED'}: ${name}${detail ? ` (${detail})` : ''}`);
}

/** Runs `check` as one test: its failure (a thrown error) is recorded and the run goes on. */
async function test(name, check) {
  try {
    record(name, true, await check());
  } catch (e) {
    record(name, false, e.message.split('\n')[0]);
  }
}

/** The tensors of a safetensors file (F32 only), by name. */
function readSafetensors(file) {
  const bytes = fs.readFileSync(file);
  const length = Number(bytes.readBigUInt64LE(0));
  const header = JSON.parse(bytes.subarray(8, 8 + length).toString('utf8'));
  const tensors = {};
  for (const [name, info] of Object.entries(header)) {
    if (name === '__metadata__') continue;
    if (info.dtype !== 'F32') throw new Error(`${file}: ${name} is ${info.dtype}, expected F32`);
    const [start, end] = info.data_offsets.map((o) => 8 + length + o);
    const data = bytes.subarray(start, end);
    tensors[name] = Array.from(new Float32Array(data.buffer.slice(data.byteOffset, data.byteOffset + data.length)));
  }
  return tensors;
}

/** Native render-frame's raw outputs for these arguments (a camera: --view or --pose), run in `cwd`; or its error
 *  message (less `render-frame: error: `) where it refuses them. */
function nativeOutputs(args, outputs, cwd = root) {
  const raw = path.join(work, `native-${results.length}-${Math.random().toString(36).slice(2)}.safetensors`);
  const run = spawnSync(renderFrame, [...args, '--outputs', outputs.join(','), '--out-raw', raw, '--out',
    path.join(work, 'native.png')], { cwd, encoding: 'utf8' });
  if (run.status !== 0) return { refused: run.stderr.trim().replace(/^render-frame: error: /, '') };
  return readSafetensors(raw);
}

/** A pose file for render-frame --pose: the page's camera (16 numbers row by row, intrinsics w, h, fx, fy, cx, cy). */
function poseFile({ pose, intrinsics: [w, h, fx, fy, cx, cy] }) {
  const file = path.join(work, `pose-${Math.random().toString(36).slice(2)}.json`);
  const rows = [0, 1, 2, 3].map((r) => pose.slice(4 * r, 4 * r + 4));
  fs.writeFileSync(file, JSON.stringify({ transform_matrix: rows, fl_x: fx, fl_y: fy, cx, cy, w, h }));
  return file;
}

/** Compares the page's and the native outputs within MAX_ABS; depth, exp(logdepth), within MAX_ABS of its size
 *  (WGSL's exp is exact to 3 + 2|x| ULP, and metres of depth grow its error with them). The largest differences. */
function compare(page, native, outputs) {
  if (native.refused) throw new Error(`render-frame refuses it: ${native.refused}`);
  const worst = [];
  for (const output of outputs) {
    const [a, b] = [page[output], native[output]];
    if (!a || !b) throw new Error(`${output}: missing (${a ? 'native' : 'page'})`);
    if (a.length !== b.length) throw new Error(`${output}: ${a.length} values on the page, ${b.length} native`);
    let most = 0;
    for (let i = 0; i < a.length; i++) {
      const d = Math.abs(a[i] - b[i]);
      const allowed = output === 'depth' ? MAX_ABS * Math.max(1, Math.abs(b[i])) : MAX_ABS;
      if (!(d <= allowed)) throw new Error(`${output}[${i}]: page ${a[i]}, native ${b[i]}: |diff| ${d} > ${allowed}`);
      most = Math.max(most, output === 'depth' ? d / Math.max(1, Math.abs(b[i])) : d);
    }
    worst.push(`${output} ${most.toExponential(1)}${output === 'depth' ? ' rel' : ''}`);
  }
  return `max |diff|: ${worst.join(', ')}`;
}

/** Serves the page's folder, and the golden cases under /golden/. */
function serve() {
  const types = { '.html': 'text/html', '.js': 'text/javascript', '.wasm': 'application/wasm', '.css': 'text/css' };
  const server = http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
    let file = url.startsWith('/golden/') ? path.join(goldenDir, url.slice(8)) : path.join(webDir, url);
    if (url.endsWith('/')) file = path.join(file, 'index.html');
    const inside = [webDir, goldenDir].some((dir) => file.startsWith(dir + path.sep));
    fs.readFile(file, (err, data) => {
      if (err || !inside) {
        res.writeHead(404);
        res.end();
        return;
      }
      res.writeHead(200, { 'content-type': types[path.extname(file)] || 'application/octet-stream' });
      res.end(data);
    });
  });
  return new Promise((resolve) => server.listen(0, '127.0.0.1', () => resolve(server)));
}

/** render-frame's message for a bad file (as it prints it, less `render-frame: error: `), run where the file is. */
function cliMessage(flag, name) {
  const run = spawnSync(renderFrame, [flag, name], { cwd: work, encoding: 'utf8' });
  return run.stderr.trim().replace(/^render-frame: error: /, '');
}

const server = await serve();
const url = `http://127.0.0.1:${server.address().port}/`;
const browser = await chromium.launchPersistentContext(fs.mkdtempSync(path.join(work, 'profile-')), {
  executablePath: chromiumPath,
  headless: true,
  args: ['--no-sandbox', '--enable-unsafe-webgpu', '--enable-unsafe-swiftshader', '--use-webgpu-adapter=swiftshader'],
});
const page = await browser.newPage();
const pageErrors = [];
page.on('pageerror', (e) => pageErrors.push(e.message));
const errorText = () => page.evaluate(() => (document.getElementById('error').hidden ? '' : document.getElementById('error').textContent));
const drawn = () => page.evaluate(() => window.app.drawn);

try {
  await test('the page shows the bundled scene', async () => {
    await page.goto(url);
    await page.waitForFunction(() => window.app && (window.app.drawn > 0 || !document.getElementById('error').hidden ||
      !document.getElementById('no-webgpu').hidden), null, { timeout: WAIT_MS });
    const error = await errorText();
    if (error) throw new Error(`the page says: ${error}`);
    const status = await page.evaluate(() => ({ adapter: document.getElementById('adapter').textContent,
      precision: document.getElementById('precision').textContent, first: window.app.firstFrameMs,
      page: window.app.sinceNavigationMs }));
    return `adapter ${status.adapter}, ${status.precision}, first frame ${status.page.toFixed(0)} ms after ` +
      `navigation, ${status.first.toFixed(0)} ms after the model's and scene's download began`;
  });

  const bundledOutputs = ['rgb'];
  const cameras = [['view 0', 0], ['orbit +30°', [0.52, 0]], ['orbit -40° up 10°', [-0.7, 0.17]]];
  for (const [name, camera] of cameras) {
    await test(`bundled scene, ${name}: page = native`, async () => {
      const asked = typeof camera === 'number' ? camera : await page.evaluate(([a, e]) => window.app.orbitCamera(a, e), camera);
      const onPage = await page.evaluate(([c, o]) => window.app.floats(c, o), [asked, bundledOutputs]);
      const args = ['--model', bundledModel, '--scene', bundledScene,
        ...(typeof camera === 'number' ? ['--view', String(camera)] : ['--pose', poseFile(asked)])];
      return compare(onPage, nativeOutputs(args, bundledOutputs), bundledOutputs);
    });
  }

  await test('frame time at the bundled size', async () => {
    const [view, orbit] = await page.evaluate(async () => [await window.app.frameMs(0, 10),
      await window.app.frameMs(window.app.orbitCamera(0.52, 0), 10)]);
    const fps = (ms) => `${ms.toFixed(1)} ms, ${(1000 / ms).toFixed(1)} fps`;
    return `view 0 (the scene's rays) ${fps(view)}; an orbit camera (a pinhole) ${fps(orbit)}; medians of 10`;
  });

  for (const golden of fs.readdirSync(goldenDir).filter((d) => fs.existsSync(path.join(goldenDir, d, 'model.safetensors'))).sort()) {
    await test(`golden ${golden}, view 0: page = native`, async () => {
      // Named as render-frame, run in assets/golden, names them: where it refuses a case, the page must say the same.
      const loaded = await page.evaluate(async (golden) => {
        const fetched = async (file) => ({ name: `${golden}/${file}`,
          bytes: new Uint8Array(await (await fetch(`golden/${golden}/${file}`)).arrayBuffer()) });
        try {
          await window.app.load({ model: await fetched('model.safetensors'), scene: await fetched('scene.safetensors') });
          return { outputs: window.app.model.outputs };
        } catch (e) {
          return { refused: e.message };
        }
      }, golden);
      const args = ['--model', `${golden}/model.safetensors`, '--scene', `${golden}/scene.safetensors`, '--view', '0'];
      const native = nativeOutputs(args, loaded.outputs || ['rgb'], goldenDir);
      if (loaded.refused || native.refused) {
        if (loaded.refused !== native.refused) {
          throw new Error(`the page says "${loaded.refused || 'nothing'}", render-frame "${native.refused || 'nothing'}"`);
        }
        return `both refuse it: "${loaded.refused}"`;
      }
      const onPage = await page.evaluate(([o]) => window.app.floats(0, o), [loaded.outputs]);
      return compare(onPage, native, loaded.outputs);
    });
  }

  // Back to the bundled model and scene for the motion, the frames folder, the hostile files and the screenshot.
  const loadBundled = () => page.evaluate(async () => {
    const fetched = async (url) => ({ name: url.split('/').pop(), bytes: new Uint8Array(await (await fetch(url)).arrayBuffer()) });
    await window.app.load({ model: await fetched('assets/fitted_scene-2000000_rpsrt_k4.safetensors'),
      scene: await fetched('assets/scene-2000000.safetensors') });
  });
  await loadBundled();

  await test('bundled scene, orbit motion frame 3 of 12: page = native', async () => {
    const onPage = await page.evaluate(() => window.app.floats({ motion: 'orbit', frames: 12, index: 3 }, ['rgb']));
    const native = nativeOutputs(['--model', bundledModel, '--scene', bundledScene, '--motion', 'orbit', '--frames', '12'],
      ['rgb']);
    if (native.refused) throw new Error(`render-frame refuses it: ${native.refused}`);
    const frame = native.rgb.length / 12;
    return compare(onPage, { rgb: native.rgb.slice(3 * frame, 4 * frame) }, ['rgb']);
  });

  // A frames folder of the bundled scene's target views: render-frame's renders as the images, the page's cameras
  // of the views (OpenGL poses and intrinsics, as transforms.json holds them); file_path without `.png`.
  const folder = path.join(work, 'frames');
  const folderCameras = await page.evaluate(() => [0, 1].map((v) => Array.from(window.app.scene.viewCamera(v))));
  const madeFolder = spawnSync(renderFrame, ['--model', bundledModel, '--scene', bundledScene, '--view', 'all',
    '--out', folder], { encoding: 'utf8' });
  const frames = folderCameras.map((camera, i) => {
    const [w, h, fx, fy, cx, cy] = camera.slice(16);
    const rows = [0, 1, 2, 3].map((r) => camera.slice(4 * r, 4 * r + 4));
    return { file_path: `view_00${i}`, transform_matrix: rows, fl_x: fx, fl_y: fy, cx, cy, w, h };
  });
  fs.writeFileSync(path.join(folder, 'transforms.json'), JSON.stringify({ frames }));

  await test('a frames folder picked on the page, view 0: page = native', async () => {
    if (madeFolder.status !== 0) throw new Error(`render-frame could not make the folder: ${madeFolder.stderr.trim()}`);
    await page.setInputFiles('#folder-file', folder);
    await page.waitForFunction(() => document.getElementById('scene-name').textContent.startsWith('frames:') ||
      !document.getElementById('error').hidden, null, { timeout: WAIT_MS });
    const error = await errorText();
    if (error) throw new Error(`the page says: ${error}`);
    const onPage = await page.evaluate(() => window.app.floats(0, ['rgb']));
    // The page encodes every frame; render-frame, reading a folder, encodes the frames not rendered unless told.
    const native = nativeOutputs(['--model', bundledModel, '--scene', 'frames', '--input-views', 'all', '--view', '0'],
      ['rgb'], work);
    return compare(onPage, native, ['rgb']);
  });

  const badFolder = path.join(work, 'bad-frames');
  fs.mkdirSync(badFolder);
  fs.copyFileSync(path.join(folder, 'view_000.png'), path.join(badFolder, 'view_000.png'));
  fs.writeFileSync(path.join(badFolder, 'transforms.json'), '{"frames": [{"file_path": "view_000",');
  await test("a corrupt transforms.json shows render-frame's message and the page renders after it", async () => {
    const before = await drawn();
    await page.setInputFiles('#folder-file', badFolder);
    await page.waitForFunction(() => document.getElementById('error').textContent.startsWith('bad-frames/'), null,
      { timeout: WAIT_MS });
    const shown = await errorText();
    const expected = cliMessage('--scene', 'bad-frames');
    if (shown !== expected) throw new Error(`the page says "${shown}", render-frame says "${expected}"`);
    await page.locator('#reset').click();
    await page.waitForFunction((n) => window.app.drawn > n, before, { timeout: WAIT_MS });
    return `"${shown}"`;
  });
  await loadBundled();
  // A second model as a visitor loads one: its file picked on the page, the bundled scene kept.
  const secondModel = path.join(root, 'assets', 'models', 'rpsrt_k2.safetensors');
  await test('a second model picked on the page renders the scene, view 0: page = native', async () => {
    await page.setInputFiles('#model-file', secondModel);
    await page.waitForFunction(() => document.getElementById('model-name').textContent.startsWith('rpsrt_k2.') ||
      !document.getElementById('error').hidden, null, { timeout: WAIT_MS });
    const error = await errorText();
    if (error) throw new Error(`the page says: ${error}`);
    const onPage = await page.evaluate(() => window.app.floats(0, ['rgb']));
    const native = nativeOutputs(['--model', secondModel, '--scene', bundledScene, '--view', '0'], ['rgb']);
    return compare(onPage, native, ['rgb']);
  });
  await loadBundled();
  const badModel = path.join(work, 'bad-model.safetensors');
  fs.writeFileSync(badModel, Buffer.concat([Buffer.from([16, 0, 0, 0, 0, 0, 0, 0]), Buffer.from('{"a": not json }')]));
  const badScene = path.join(work, 'bad-scene.safetensors');
  fs.writeFileSync(badScene, fs.readFileSync(bundledScene).subarray(0, 5000)); // cut short
  for (const [what, input, file, flag] of [['model', '#model-file', badModel, '--model'], ['scene', '#scene-file', badScene, '--scene']]) {
    await test(`a corrupt ${what} shows render-frame's message and the page renders after it`, async () => {
      const before = await drawn();
      await page.setInputFiles(input, file);
      await page.waitForFunction((name) => document.getElementById('error').textContent.startsWith(name),
        path.basename(file), { timeout: WAIT_MS });
      const shown = await errorText();
      const expected = cliMessage(flag, path.basename(file));
      if (shown !== expected) throw new Error(`the page says "${shown}", render-frame says "${expected}"`);
      const box = await page.locator('#view').boundingBox();
      await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
      await page.mouse.down();
      await page.mouse.move(box.x + box.width / 2 + 40, box.y + box.height / 2 + 10, { steps: 4 });
      await page.mouse.up();
      await page.waitForFunction((n) => window.app.drawn > n, before, { timeout: WAIT_MS });
      return `"${shown}"`;
    });
  }

  await test('a screenshot after a render is not blank', async () => {
    const shot = path.join(webDir, 'screenshot.png');
    await page.screenshot({ path: shot });
    const spread = await page.evaluate(() => {
      const canvas = document.getElementById('view');
      const { data } = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height);
      const values = data.filter((_, i) => i % 4 !== 3);
      const mean = values.reduce((s, v) => s + v, 0) / values.length;
      return Math.sqrt(values.reduce((s, v) => s + (v - mean) ** 2, 0) / values.length);
    });
    if (!(spread > 10)) throw new Error(`the view's pixels spread by ${spread.toFixed(1)} levels: blank`);
    return `${shot}, pixel spread ${spread.toFixed(1)} levels`;
  });

  await test('no uncaught error on the page', async () => {
    if (pageErrors.length) throw new Error(pageErrors.join('; '));
  });

  await test('without WebGPU the page says so', async () => {
    // Chromium without --enable-unsafe-webgpu offers no adapter here.
    const plain = await chromium.launchPersistentContext(fs.mkdtempSync(path.join(work, 'plain-')), {
      executablePath: chromiumPath, headless: true, args: ['--no-sandbox'],
    });
    try {
      const other = await plain.newPage();
      await other.goto(url);
      await other.waitForSelector('#no-webgpu:not([hidden])', { timeout: WAIT_MS });
      return `"${await other.textContent('#adapter')}"`;
    } finally {
      await plain.close();
    }
  });
} finally {
  await browser.close();
  server.close();
  fs.rmSync(work, { recursive: true, force: true });
}

const failed = results.filter((ok) => !ok).length;
console.log(`web: ${results.length - failed} passed, ${failed} failed`);
process.exitCode = failed ? 1 : 0;
