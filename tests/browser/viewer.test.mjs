// The viewer in a real browser: headless Chromium (Debian's package) driven by Playwright loads the page of
// `render-frame --serve`, waits for the first frame, drags, checks that a new and different frame arrives,
// compares a screenshot of the view with `render-frame --pose`'s PNG of the same camera, and switches output.
//
//   node viewer.test.mjs   (from tests/browser, after `npm ci` and `cargo build --release -p raypatch-cli`)
//
// RENDER_FRAME (default ../../target/release/render-frame), CHROMIUM (default /usr/bin/chromium) and OUT_DIR
// (default ../../target/browser: the screenshots) change where things are.
import { spawn, execFileSync } from 'node:child_process';
import { once } from 'node:events';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '../..');
const renderFrame = process.env.RENDER_FRAME || path.join(root, 'target/release/render-frame');
const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
const outDir = process.env.OUT_DIR || path.join(root, 'target/browser');
// The screenshot and the engine's PNG are the same pixels; the margin allows for colour handling in the browser.
const MIN_PSNR_DB = 40;
const WAIT_MS = 120_000;

function fail(message) {
  console.error(`browser test: FAILED: ${message}`);
  process.exitCode = 1;
  throw new Error(message);
}

function check(condition, message) {
  if (!condition) fail(message);
}

/** Starts the viewer on a free port with the bundled model and the golden OSRT model (it has masks). */
async function startServer() {
  const server = spawn(renderFrame, [
    '--serve', '--port', '0',
    '--model', path.join(root, 'assets/models/fitted_scene-2000000_rpsrt_k4.safetensors'),
    '--model', path.join(root, 'assets/golden/osrt/model.safetensors'),
  ], { stdio: ['ignore', 'pipe', 'inherit'] });
  let output = '';
  server.stdout.setEncoding('utf8');
  const url = await new Promise((resolve, reject) => {
    server.stdout.on('data', (chunk) => {
      output += chunk;
      const found = output.match(/http:\/\/\S+\//);
      if (found) resolve(found[0]);
    });
    server.on('exit', (code) => reject(new Error(`render-frame --serve exited with ${code} before serving: ${output}`)));
  });
  return { server, url };
}

/** What the view shows: the frame's number, size, output, model and pose, once its image has loaded. */
function frameInfo(page) {
  return page.evaluate(() => {
    const img = document.getElementById('view');
    return { ...img.dataset, loaded: img.complete && img.naturalWidth > 0 };
  });
}

/** Waits until the newest frame asked for is shown, full-size (80x60), newer than frame `after`, of `output` and
 *  `model` (the camera has settled), and returns it (read in the same check, so that no later frame slips in). */
async function waitForFrame(page, what, { after = 0, output = 'rgb', model = '0' } = {}) {
  try {
    const found = await page.waitForFunction(([after, output, model]) => {
      const img = document.getElementById('view');
      const frame = img.dataset;
      return +frame.frame > after && +frame.frame === window.viewer.sent && img.complete && img.naturalWidth > 0 && frame.size === '80x60' &&
        frame.output === output && frame.model === model && { ...frame };
    }, [+after, output, model], { timeout: WAIT_MS, polling: 50 });
    return await found.jsonValue();
  } catch (e) {
    fail(`${what}: ${e.message.split('\n')[0]} (last frame ${JSON.stringify(await frameInfo(page))}, error line: ` +
      `${await page.textContent('#error')})`);
  }
}

/** The view's image pixels as drawn on a canvas (RGBA). */
function viewPixels(page) {
  return page.evaluate(() => {
    const img = document.getElementById('view');
    const canvas = Object.assign(document.createElement('canvas'), { width: img.naturalWidth, height: img.naturalHeight });
    const context = canvas.getContext('2d');
    context.drawImage(img, 0, 0);
    return Array.from(context.getImageData(0, 0, canvas.width, canvas.height).data);
  });
}

/** PSNR of a screenshot of the view (the frame scaled up by a whole factor, nearest neighbour) against a PNG of
 *  width x height, both decoded by the browser. */
function screenshotPsnr(page, screenshot, reference, width, height) {
  return page.evaluate(async ([shot, ref, w, h]) => {
    const load = (b64) => new Promise((resolve, reject) => {
      const img = new Image();
      img.onload = () => resolve(img);
      img.onerror = () => reject(new Error('cannot decode a PNG'));
      img.src = `data:image/png;base64,${b64}`;
    });
    const pixels = (img) => {
      const canvas = Object.assign(document.createElement('canvas'), { width: w, height: h });
      const context = canvas.getContext('2d');
      context.imageSmoothingEnabled = false; // one screenshot pixel per frame pixel, from inside its block
      context.drawImage(img, 0, 0, w, h);
      return context.getImageData(0, 0, w, h).data;
    };
    const [a, b] = (await Promise.all([load(shot), load(ref)])).map(pixels);
    let sum = 0;
    for (let i = 0; i < a.length; i++) if (i % 4 !== 3) sum += (a[i] - b[i]) ** 2;
    const mse = sum / (w * h * 3);
    return mse === 0 ? Infinity : 10 * Math.log10(255 ** 2 / mse);
  }, [screenshot.toString('base64'), reference.toString('base64'), width, height]);
}

async function run() {
  fs.mkdirSync(outDir, { recursive: true });
  const { server, url } = await startServer();
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'raypatch-chromium-'));
  let browser = null;
  try {
    // A fresh profile each run.
    browser = await chromium.launchPersistentContext(userDataDir, {
      executablePath: chromiumPath,
      headless: true,
      args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
        '--disable-sync'],
      viewport: { width: 1200, height: 760 },
      deviceScaleFactor: 1,
    });
    const page = await browser.newPage();
    const pageErrors = [];
    page.on('pageerror', (e) => pageErrors.push(e.message));
    await page.goto(url);

    const first = await waitForFrame(page, 'the first full-size frame');
    const firstPixels = await viewPixels(page);
    check((await page.textContent('#stats')).match(/RP-SRT.*k=4.*render [\d.]+ ms.*\d+ fps/), 'the stats line');
    check((await page.$$('#inputs img')).length > 0, 'the input thumbnails');

    // Drag across the view: preview frames (half size) while moving, then a full-size frame of the new camera.
    await page.evaluate(() => {
      window.shownSizes = [];
      const img = document.getElementById('view');
      new MutationObserver(() => window.shownSizes.push(img.dataset.size))
        .observe(img, { attributes: true, attributeFilter: ['data-frame'] });
    });
    const box = await page.locator('#stage').boundingBox();
    const [x, y] = [box.x + box.width / 2, box.y + box.height / 2];
    await page.mouse.move(x, y);
    await page.mouse.down();
    for (let i = 1; i <= 20; i++) {
      await page.mouse.move(x + 6 * i, y + 2 * i);
      await page.waitForTimeout(50);
    }
    await page.mouse.up();
    const moved = await waitForFrame(page, 'a full-size frame after the drag', { after: first.frame });
    check(moved.pose !== first.pose, 'the drag moved the camera');
    const sizes = await page.evaluate(() => window.shownSizes);
    check(sizes.includes('40x28'), `no preview frame (40x28) while dragging: frames of ${sizes.join(', ')}`);
    const movedPixels = await viewPixels(page);
    const meanDifference = movedPixels.reduce((s, v, i) => s + Math.abs(v - firstPixels[i]), 0) / movedPixels.length;
    check(meanDifference > 1, `the new frame differs from the first (mean difference ${meanDifference.toFixed(3)})`);

    // The screenshot of the view against the engine's PNG of the same camera.
    const screenshot = await page.locator('#view').screenshot({ path: path.join(outDir, 'view.png') });
    await page.screenshot({ path: path.join(outDir, 'viewer.png') });
    const rows = moved.pose.split(',').map(Number);
    const poseFile = path.join(outDir, 'pose.json');
    fs.writeFileSync(poseFile, JSON.stringify({ transform_matrix: [0, 1, 2, 3].map((r) => rows.slice(4 * r, 4 * r + 4)) }));
    const referenceFile = path.join(outDir, 'reference.png');
    execFileSync(renderFrame, ['--pose', poseFile, '--out', referenceFile], { stdio: ['ignore', 'ignore', 'inherit'] });
    const psnr = await screenshotPsnr(page, screenshot, fs.readFileSync(referenceFile), 80, 60);
    check(psnr >= MIN_PSNR_DB, `screenshot vs render-frame --pose: PSNR ${psnr.toFixed(1)} dB < ${MIN_PSNR_DB} dB`);

    // Scroll, a key and a camera button each bring a new full-size frame of their camera.
    let last = moved;
    const nextFrame = (what) => waitForFrame(page, what, { after: last.frame });
    await page.mouse.wheel(0, 300);
    const zoomed = await nextFrame('a frame after scrolling');
    check(zoomed.pose !== last.pose, 'scrolling moved the camera');
    last = zoomed;
    await page.keyboard.press('w');
    const walked = await nextFrame('a frame after the W key');
    check(walked.pose !== last.pose, 'the W key moved the camera');
    last = walked;
    await page.click('#targets button:nth-child(2)');
    const jumped = await nextFrame('a frame after the target 1 button');
    last = jumped;
    const target = await page.evaluate(() => fetch('/api/info').then((r) => r.json()).then((i) => i.scenes[0].targets[1].pose));
    const shownPose = jumped.pose.split(',').map(Number);
    check(shownPose.every((v, i) => Math.abs(v - target[i]) < 1e-9), `target 1's button shows pose ${jumped.pose}`);

    // Switch to the OSRT model and its masks.
    check((await page.$$eval('#output option', (o) => o.map((e) => e.value))).join() === 'rgb', 'RP-SRT renders rgb only');
    await page.selectOption('#model', '1');
    await page.selectOption('#output', 'masks');
    await waitForFrame(page, 'a masks frame of the OSRT model', { after: last.frame, output: 'masks', model: '1' });
    await page.locator('#view').screenshot({ path: path.join(outDir, 'masks.png') });
    check(pageErrors.length === 0, `errors in the page: ${pageErrors.join('; ')}`);
    console.log(`browser test: ok (screenshot vs render-frame --pose: PSNR ${psnr === Infinity ? 'inf' : psnr.toFixed(1)} dB; ` +
      `screenshots in ${path.relative(root, outDir)})`);
  } finally {
    await browser?.close();
    fs.rmSync(userDataDir, { recursive: true, force: true });
    server.kill('SIGINT');
    const [code] = await once(server, 'exit');
    // 128 + SIGINT: stopped by the signal, its temporaries removed (raypatch::clean_up_on_signals_then).
    if (code !== 130) fail(`render-frame --serve exited with ${code} on Ctrl-C, expected 130`);
  }
}

run().catch((e) => {
  if (!process.exitCode) console.error(`browser test: FAILED: ${e.stack || e}`);
  process.exitCode = 1;
});
