// End-to-end test of the web viewer in headless Chromium, against a running
// `treemorph serve`:
//
//   TREEMORPH_URL=http://127.0.0.1:8080 npm run browser-test --prefix web -- [options]
//
// Options:
//   --url URL            the server (default $TREEMORPH_URL)
//   --serve BIN          instead: start `BIN serve` on a free port with a fresh
//                        data directory and this web/ folder, and stop it after
//   --screenshots DIR    save screenshots there (mid-morph.png is the README's)
//   --frames N           frames per job (default 12)
//   --size N             branches of the generated trees (default 60: fast)
//   --timeout S          seconds to wait for each job (default 600)
//   --expect-streaming   fail unless a frame was on screen before the morph
//                        finished (use with big trees or a slow runner; a
//                        small morph may finish before the page sees it run)
//   --static             serve web/ from disk for /, /app/ and /vendor/ (for a
//                        server without the static route); /v1 still goes to it
//   --headed             show the browser (needs a display)
//
// $TREEMORPH_API_KEY, when set, is pasted into the page's key field.
// Chromium is Debian's /usr/bin/chromium (or $CHROMIUM).
//
// Steps: render the committed stream fixture (api/tests/fixtures/small.tmd)
// through the page's player to check the leaf cross-fade dissolve in WebGL;
// upload a broken file and see the API error as `code: message`; generate
// two small trees (the view is not blank); upload one's GLB by drag and
// drop; morph one into the other (the timeline's max and value advance, the
// canvas is not blank, first and last frames differ, with
// --expect-streaming frames were shown before the job ended); scrub half way
// between two frames (the server renders that instant: it is neither frame
// and lies between them); download
// animation.glb through its link; draw a closed diamond around the crown on
// the sketch pad (the NDC and view sent are checked) and run the sketch job
// to completion; shrink the window to 420 px. It exits non-zero with a
// message naming the failed step, the page's errors and failed requests.

import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { spawn } from 'node:child_process';
import os from 'node:os';
import { chromium } from 'playwright-core';

const webDir = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');

function parseArgs(argv) {
  const o = { url: process.env.TREEMORPH_URL || '', serve: null, screenshots: null, frames: 12, size: 60, timeout: 600, static: false, headed: false, expectStreaming: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => {
      if (i + 1 >= argv.length) throw new Error(`${a} needs a value`);
      return argv[++i];
    };
    if (a === '--url') o.url = next();
    else if (a === '--serve') o.serve = path.resolve(process.env.INIT_CWD || process.cwd(), next());
    // Relative to where the command was typed (npm --prefix runs us in web/).
    else if (a === '--screenshots') o.screenshots = path.resolve(process.env.INIT_CWD || process.cwd(), next());
    else if (a === '--frames') o.frames = Number(next());
    else if (a === '--size') o.size = Number(next());
    else if (a === '--timeout') o.timeout = Number(next());
    else if (a === '--static') o.static = true;
    else if (a === '--headed') o.headed = true;
    else if (a === '--expect-streaming') o.expectStreaming = true;
    else throw new Error(`unknown option ${a}`);
  }
  if (!o.url && !o.serve) throw new Error('give the server: --url URL, TREEMORPH_URL or --serve BIN');
  o.url = o.url.replace(/\/$/, '');
  return o;
}

const MIME = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.css': 'text/css; charset=utf-8',
  '.json': 'application/json',
  '.png': 'image/png',
  '.wasm': 'application/wasm',
};

/** The server's static-route contract, from disk (for --static). */
function staticFile(pathname) {
  let file = null;
  if (pathname === '/' || pathname === '/index.html') file = 'index.html';
  else if (pathname.startsWith('/app/')) file = pathname.slice(5);
  else if (pathname.startsWith('/vendor/three/')) file = `node_modules/three/${pathname.slice(14)}`;
  else if (pathname.startsWith('/vendor/fzstd/')) file = `node_modules/fzstd/${pathname.slice(14)}`;
  if (file === null) return null;
  const full = path.resolve(webDir, decodeURIComponent(file));
  if (!full.startsWith(webDir + path.sep)) return null;
  return full;
}

let step = 'starting';
const log = (m) => console.log(`  ${m}`);
function begin(name) {
  step = name;
  console.log(`- ${name}`);
}

/**
 * Starts `bin serve` on a free port; resolves to `{url, stop}` once it
 * prints its address. Its log goes to stderr only if it fails to start.
 */
function startServer(bin) {
  const dataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'treemorph-browser-test-'));
  const child = spawn(bin, ['serve', '--listen', '127.0.0.1:0', '--data-dir', dataDir, '--web-dir', webDir], {
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  let log = '';
  child.stderr.on('data', (d) => {
    log += d;
  });
  const stop = () =>
    new Promise((resolve) => {
      if (child.exitCode !== null) return resolve();
      child.once('exit', resolve);
      child.kill('SIGTERM');
    }).finally(() => fs.rmSync(dataDir, { recursive: true, force: true }));
  return new Promise((resolve, reject) => {
    let out = '';
    const timer = setTimeout(() => reject(new Error(`${bin} serve did not report its address in 60 s:\n${log}`)), 60_000);
    child.on('error', (e) => reject(new Error(`cannot run ${bin}: ${e.message}`)));
    child.on('exit', (code) => reject(new Error(`${bin} serve exited with ${code}:\n${log}`)));
    child.stdout.on('data', (d) => {
      out += d;
      const m = /listening on (http:\/\/\S+)/.exec(out);
      if (m) {
        clearTimeout(timer);
        resolve({ url: m[1], stop });
      }
    });
  });
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  let server = null;
  if (opts.serve) {
    begin(`starting ${opts.serve} serve`);
    server = await startServer(opts.serve);
    opts.url = server.url;
  }
  try {
    await test(opts);
  } finally {
    if (server) await server.stop();
  }
}

async function test(opts) {
  if (opts.screenshots) fs.mkdirSync(opts.screenshots, { recursive: true });

  begin(`checking ${opts.url}`);
  const health = await fetch(`${opts.url}/v1/trees?limit=1`, {
    headers: process.env.TREEMORPH_API_KEY ? { Authorization: `Bearer ${process.env.TREEMORPH_API_KEY}` } : {},
  }).catch((e) => {
    throw new Error(`the server at ${opts.url} is not reachable (${e.cause?.code || e.message}); start \`treemorph serve\` first`);
  });
  if (!health.ok) throw new Error(`GET /v1/trees answered ${health.status}: ${await health.text()}`);
  if (!opts.static) {
    const index = await fetch(`${opts.url}/`);
    const type = index.headers.get('content-type') || '';
    if (!index.ok || !type.includes('text/html')) {
      throw new Error(`GET / answered ${index.status} (${type}), not the viewer's page: the server has no static route for web/ (pass --static to serve web/ from disk)`);
    }
  }

  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: !opts.headed,
    args: [
      '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    ],
  });
  const context = await browser.newContext({ viewport: { width: 1280, height: 800 }, acceptDownloads: true });
  const page = await context.newPage();
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(`page error: ${e.message}`));
  // Chromium's console message for a failed load does not name the URL: keep them for the report.
  const failedUrls = [];
  page.on('response', (r) => {
    if (r.status() >= 400) failedUrls.push(`${r.status()} ${r.request().method()} ${r.url()}`);
  });
  page.on('console', (m) => {
    if (m.type() !== 'error') return;
    const text = m.text();
    pageErrors.push(`console error: ${text}`);
  });
  if (process.env.TREEMORPH_API_KEY) {
    await page.addInitScript((key) => localStorage.setItem('treemorph.apiKey', key), process.env.TREEMORPH_API_KEY);
  }
  if (opts.static) {
    await page.route(`${opts.url}/**`, async (route) => {
      const file = staticFile(new URL(route.request().url()).pathname);
      if (!file) return route.continue();
      if (!fs.existsSync(file)) return route.fulfill({ status: 404, body: 'not found' });
      return route.fulfill({ status: 200, body: fs.readFileSync(file), headers: { 'Content-Type': MIME[path.extname(file)] || 'application/octet-stream' } });
    });
  }

  const shot = async (name, locator = null) => {
    const buffer = locator ? await locator.screenshot() : await page.screenshot();
    if (opts.screenshots) {
      const file = path.join(opts.screenshots, name);
      fs.writeFileSync(file, buffer);
      log(`screenshot ${file}`);
    }
    return buffer;
  };
  /** Pixel statistics of a PNG, computed by the browser's own decoder. */
  const pixels = (png, other = null) =>
    page.evaluate(
      async ([a, b]) => {
        const decode = async (b64) => {
          const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
          const bmp = await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
          const c = new OffscreenCanvas(bmp.width, bmp.height);
          const ctx = c.getContext('2d');
          ctx.drawImage(bmp, 0, 0);
          return ctx.getImageData(0, 0, bmp.width, bmp.height).data;
        };
        const da = await decode(a);
        const bg = [0xdd, 0xe7, 0xee];
        let nonBackground = 0;
        let differ = 0;
        const db = b ? await decode(b) : null;
        for (let i = 0; i < da.length; i += 4) {
          if (Math.abs(da[i] - bg[0]) + Math.abs(da[i + 1] - bg[1]) + Math.abs(da[i + 2] - bg[2]) > 24) nonBackground++;
          if (db && Math.abs(da[i] - db[i]) + Math.abs(da[i + 1] - db[i + 1]) + Math.abs(da[i + 2] - db[i + 2]) > 24) differ++;
        }
        const n = da.length / 4;
        return { nonBackground: nonBackground / n, differ: differ / n };
      },
      [png.toString('base64'), other ? other.toString('base64') : null],
    );
  const expect = (cond, message) => {
    if (!cond) throw new Error(message);
  };
  const canvas = page.locator('#view');
  /** Bodies of the POST /v1/jobs requests the page sent. */
  const jobRequests = [];
  page.on('request', (r) => {
    if (r.method() === 'POST' && new URL(r.url()).pathname === '/v1/jobs') jobRequests.push(JSON.parse(r.postData()));
  });
  const jobTimeout = opts.timeout * 1000;

  try {
    begin('opening the page');
    await page.goto(`${opts.url}/`, { waitUntil: 'load' });
    await page.waitForFunction(() => window.treemorph !== undefined, null, { timeout: 30_000 });

    begin('checking the stream player and the leaf dissolve in WebGL (committed fixture small.tmd)');
    const fixture = fs.readFileSync(path.join(webDir, '..', 'api', 'tests', 'fixtures', 'small.tmd'));
    const shares = await page.evaluate(async (b64) => {
      const THREE = await import('three');
      const { decodeAll } = await import('/app/delta.js');
      const { StreamPlayer } = await import('/app/player.js');
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const player = new StreamPlayer();
      const decoder = decodeAll(bytes);
      player.handle({ type: 'header', header: decoder.header });
      for (const frame of decoder.frames) player.handle({ type: 'frame', frame });
      player.handle({ type: 'end', frames: decoder.frames.length });
      await player.texturesReady;
      player.meshes.find((m) => m.name === 'branches').mesh.visible = false;
      const size = 128;
      const renderer = new THREE.WebGLRenderer();
      const target = new THREE.WebGLRenderTarget(size, size);
      const scene = new THREE.Scene();
      scene.background = new THREE.Color(0, 0, 0);
      scene.add(new THREE.AmbientLight(0xffffff, 3), player.group);
      const camera = new THREE.PerspectiveCamera(30, 1, 0.01, 10);
      camera.position.set(0, 1.69, 0.7);
      camera.lookAt(0, 1.69, 0.025);
      const out = [];
      const buf = new Uint8Array(size * size * 4);
      for (const i of [0, 3, 4]) {
        const frame = player.show(i);
        renderer.setRenderTarget(target);
        renderer.render(scene, camera);
        renderer.readRenderTargetPixels(target, 0, 0, size, size, buf);
        let green = 0;
        let red = 0;
        for (let k = 0; k < buf.length; k += 4) {
          const [r, g, b] = [buf[k], buf[k + 1], buf[k + 2]];
          if (r + g + b < 6) continue;
          if (g > 4 * r) green++;
          else red++;
        }
        out.push({ frame: i, blend: frame.leafBlend, red: red / Math.max(1, red + green), pixels: red + green });
      }
      renderer.dispose();
      player.dispose();
      return out;
    }, fixture.toString('base64'));
    for (const s of shares) log(`frame ${s.frame}: leaf blend ${s.blend.toFixed(3)} → ${(s.red * 100).toFixed(1)}% of ${s.pixels} leaf pixels show fade_to`);
    expect(shares.every((s) => s.pixels > 200), 'the fixture leaves did not render');
    for (const s of shares) {
      expect(Math.abs(s.red - s.blend) < 0.12, `frame ${s.frame}: ${(s.red * 100).toFixed(1)}% of pixels show the fade_to material at leaf blend ${s.blend}`);
    }

    begin('uploading an invalid tree: the API error is shown as code and message');
    await page.setInputFiles('#upload-file', { name: 'broken.json', mimeType: 'application/json', buffer: Buffer.from('{"nodes": 1}') });
    await page.click('#upload-form button[type=submit]');
    await page.waitForSelector('#errors li', { timeout: 30_000 });
    const shown = await page.textContent('#errors li');
    log(shown);
    expect(/^invalid_\w+: .+uploading broken\.json/.test(shown), `the error is not shown as code: message (“${shown}”)`);
    // The page logs the error it shows (and Chromium the 422): expected here.
    const unexpected = pageErrors.filter((m) => !/422|broken\.json/.test(m));
    pageErrors.splice(0, pageErrors.length, ...unexpected);
    await page.click('#errors li button');
    expect((await page.locator('#errors li').count()) === 0, 'the error could not be dismissed');

    const generate = async (preset, seed) => {
      const before = await page.locator('#tree-list > li').count();
      await page.selectOption('#gen-preset', preset);
      await page.fill('#gen-seed', String(seed));
      await page.fill('#gen-size', String(opts.size));
      await page.click('#generate');
      await page.waitForFunction((n) => document.querySelectorAll('#tree-list > li').length > n, before, { timeout: 120_000 });
      const id = await page.locator('#tree-list > li').first().getAttribute('data-id');
      const name = await page.locator('#tree-list > li .tree-view').first().textContent();
      // The new tree is shown: the caption names it once its GLB is on screen.
      await page.waitForFunction((n) => document.getElementById('caption').textContent === n, name, { timeout: 60_000 });
      log(`${name}: ${await page.locator('#tree-list > li .stats').first().textContent()}`);
      return { id, name };
    };

    begin('generating two trees');
    const a = await generate('maple', 1);
    const b = await generate('conifer', 2);
    await page.waitForTimeout(300);
    const treeShot = await shot('tree.png', canvas);
    const treeStats = await pixels(treeShot);
    log(`tree view: ${(treeStats.nonBackground * 100).toFixed(1)}% non-background pixels`);
    expect(treeStats.nonBackground > 0.02, `the tree view looks blank (${(treeStats.nonBackground * 100).toFixed(2)}% non-background)`);

    begin(`uploading ${b.name}'s GLB by drag and drop`);
    const model = await page.request.get(`${opts.url}/v1/trees/${b.id}/model.glb`, {
      headers: process.env.TREEMORPH_API_KEY ? { Authorization: `Bearer ${process.env.TREEMORPH_API_KEY}` } : {},
    });
    expect(model.ok(), `GET model.glb answered ${model.status()}`);
    const countBefore = await page.locator('#tree-list > li').count();
    await page.evaluate(async (b64) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const dt = new DataTransfer();
      dt.items.add(new File([bytes], 'dropped-conifer.glb', { type: 'model/gltf-binary' }));
      const target = document.getElementById('canvas-wrap');
      target.dispatchEvent(new DragEvent('dragenter', { dataTransfer: dt, bubbles: true }));
      if (document.getElementById('drop-hint').hidden) throw new Error('no drop hint while dragging a file');
      target.dispatchEvent(new DragEvent('dragover', { dataTransfer: dt, bubbles: true, cancelable: true }));
      target.dispatchEvent(new DragEvent('drop', { dataTransfer: dt, bubbles: true, cancelable: true }));
    }, (await model.body()).toString('base64'));
    await page.waitForFunction((n) => document.querySelectorAll('#tree-list > li').length > n, countBefore, { timeout: 120_000 });
    const dropped = await page.locator('#tree-list > li').first().textContent();
    log(dropped);
    expect(/dropped-conifer/.test(dropped) && /glb/.test(dropped), `the dropped file is not listed as a GLB tree: ${dropped}`);
    await page.waitForFunction(() => document.getElementById('caption').textContent === 'dropped-conifer', null, { timeout: 60_000 });
    expect(await page.locator('#drop-hint').isHidden(), 'the drop hint stayed on screen');

    begin(`morphing ${a.name} into ${b.name} (${opts.frames} frames)`);
    await page.selectOption('#morph-source', a.id);
    await page.selectOption('#morph-target', b.id);
    await page.fill('#morph-frames', String(opts.frames));
    await page.click('#morph-run');
    // Frames play while they stream: the timeline gains frames before the job ends.
    await page.waitForFunction(() => Number(document.getElementById('scrub').max) >= 1, null, { timeout: jobTimeout });
    const seen = new Set();
    const maxima = new Set();
    let midShot = null;
    let shownWhileRunning = false;
    const started = Date.now();
    for (;;) {
      const state = await page.evaluate(() => ({
        max: Number(document.getElementById('scrub').max),
        value: Number(document.getElementById('scrub').value),
        status: document.getElementById('job-status').textContent,
      }));
      seen.add(state.value);
      maxima.add(state.max);
      if (!/succeeded/.test(state.status) && state.max < opts.frames - 1) shownWhileRunning = true;
      if (!midShot && state.value > 0 && state.value < opts.frames - 1) {
        midShot = await shot('mid-morph.png');
        log(`mid-morph at frame ${state.value + 1} (${state.max + 1} received): ${state.status}`);
      }
      if (/succeeded|failed|cancelled/.test(state.status) && state.max === opts.frames - 1 && seen.size >= 3) break;
      if (/failed|cancelled/.test(state.status)) throw new Error(`the morph job ended: ${state.status}`);
      if (Date.now() - started > jobTimeout) throw new Error(`the morph did not finish in ${opts.timeout} s: ${state.status}`);
      await page.waitForTimeout(60);
    }
    const status = await page.textContent('#job-status');
    expect(/succeeded/.test(status), `the morph job did not succeed: ${status}`);
    log(`timeline maxima seen ${[...maxima].sort((x, y) => x - y).join(',')}; values ${[...seen].sort((x, y) => x - y).join(',')}`);
    log(shownWhileRunning ? 'frames were on screen while the job ran' : 'the job finished before the page saw it run');
    expect(shownWhileRunning || !opts.expectStreaming, 'no frame was shown before the morph finished (--expect-streaming)');
    expect(seen.size >= 3, `playback did not advance (frames shown: ${[...seen].join(', ')})`);
    expect(Number(await page.getAttribute('#scrub', 'max')) === opts.frames - 1, 'the timeline does not cover every frame');

    begin('scrubbing the morph');
    await page.click('#play'); // pause (it plays on its own)
    if ((await page.getAttribute('#play', 'aria-pressed')) === 'true') await page.click('#play');
    await page.focus('#scrub');
    await page.keyboard.press('Home');
    await page.waitForTimeout(200);
    const first = await shot('morph-first.png', canvas);
    await page.keyboard.press('End');
    await page.waitForTimeout(200);
    const last = await shot('morph-last.png', canvas);
    const label = await page.textContent('#frame-label');
    expect(label.startsWith(`frame ${opts.frames} / ${opts.frames}`), `the frame label after End is “${label}”`);
    const diff = await pixels(first, last);
    const lastStats = await pixels(last);
    log(`first vs last frame: ${(diff.differ * 100).toFixed(1)}% of pixels differ; last frame ${(lastStats.nonBackground * 100).toFixed(1)}% non-background`);
    expect(lastStats.nonBackground > 0.001, 'the last frame looks blank');
    expect(diff.differ > 0.0005, 'the first and last frames look the same: nothing moved');

    begin('scrubbing between frames');
    // Half way between frames 2 and 3 (0-based 1 and 2): the server renders
    // the instant, which is neither frame.
    const between = await page.evaluate(async () => {
      const tl = window.treemorph.timeline;
      const player = tl.player;
      const scrub = document.getElementById('scrub');
      const positions = () => player.meshes.map((m) => Array.from(m.geometry.attributes.position.array));
      tl.scrubTo(1);
      const a = positions();
      tl.scrubTo(2);
      const b = positions();
      scrub.value = '1.5';
      scrub.dispatchEvent(new Event('input'));
      const wanted = tl.instant;
      const deadline = Date.now() + 60_000;
      while (tl.shownInstant !== wanted && !tl.instantError && Date.now() < deadline) {
        await new Promise((r) => setTimeout(r, 20));
      }
      const c = positions();
      // Mean distance from the instant's positions to each frame's, and between the frames.
      const dist = (x, y) => {
        let sum = 0;
        let n = 0;
        for (let m = 0; m < x.length; m++)
          for (let i = 0; i < x[m].length; i += 3) {
            sum += Math.hypot(x[m][i] - y[m][i], x[m][i + 1] - y[m][i + 1], x[m][i + 2] - y[m][i + 2]);
            n += 1;
          }
        return sum / Math.max(1, n);
      };
      return {
        wanted,
        shown: tl.shownInstant,
        error: tl.instantError ? String(tl.instantError.message) : null,
        label: document.getElementById('frame-label').textContent,
        value: Number(scrub.value),
        toA: dist(c, a),
        toB: dist(c, b),
        ab: dist(a, b),
        fetches: tl.instants ? tl.instants.fetches : 0,
      };
    });
    log(`instant ${between.wanted} (${between.label}): ${between.toA.toExponential(2)} m from frame 2, ${between.toB.toExponential(2)} m from frame 3, frames ${between.ab.toExponential(2)} m apart`);
    expect(between.error === null, `the instant between frames failed: ${between.error}`);
    expect(between.wanted !== null && between.shown === between.wanted, `the instant under the cursor was not shown (wanted ${between.wanted}, shown ${between.shown})`);
    expect(between.value === 1.5, `the timeline snapped to ${between.value}`);
    expect(/^t 0\.\d{4} · after frame 2 /.test(between.label), `the label between frames is “${between.label}”`);
    // Both frames are on the stream's grid, as is the instant: a copy of either would be 0 away.
    // (Staged timing eases, so the middle instant need not be half way in space.)
    expect(between.toA > 0 && between.toB > 0, 'the instant between frames is one of the frames');
    expect(between.toA < between.ab && between.toB < between.ab, 'the instant between frames is farther from them than they are from each other');
    await shot('morph-between.png', canvas);
    await page.evaluate(() => window.treemorph.timeline.scrubTo(2));
    const backLabel = await page.textContent('#frame-label');
    expect(backLabel.startsWith(`frame 3 / ${opts.frames}`), `back on a frame, the label is “${backLabel}”`);

    begin('downloading the animation');
    // Through the link, as a person would (with a key the page fetches it with the header).
    const link = page.locator('#downloads a[href$="animation.glb"]');
    expect((await link.count()) === 1, 'no animation.glb download link');
    const [download] = await Promise.all([page.waitForEvent('download', { timeout: 120_000 }), link.click()]);
    const glbBytes = fs.readFileSync(await download.path());
    expect(glbBytes.subarray(0, 4).toString() === 'glTF', `the downloaded animation is not a GLB: ${glbBytes.subarray(0, 16)}`);
    expect(download.suggestedFilename().endsWith('.glb'), `downloaded as ${download.suggestedFilename()}`);
    log(`animation.glb: ${glbBytes.length} bytes`);

    begin(`sketching a diamond over ${a.name}`);
    await page.click(`#tree-list > li[data-id="${a.id}"] .tree-view`);
    await page.waitForFunction((n) => document.getElementById('caption').textContent === n, a.name, { timeout: 60_000 });
    await page.click('#sketch-toggle');
    expect((await page.getAttribute('#sketch-toggle', 'aria-pressed')) === 'true', 'the sketch pad did not turn on');
    await page.check('#sketch-closed');
    const box = await page.locator('#sketch-overlay').boundingBox();
    const side = Math.min(box.width, box.height);
    const cx = box.x + box.width / 2;
    const cy = box.y + box.height / 2;
    // The tree is framed to fill the view; its crown is the upper part.
    const diamond = [
      [cx, cy - 0.42 * side],
      [cx + 0.3 * side, cy - 0.12 * side],
      [cx, cy + 0.18 * side],
      [cx - 0.3 * side, cy - 0.12 * side],
      [cx, cy - 0.4 * side],
    ];
    await page.mouse.move(...diamond[0]);
    await page.mouse.down();
    for (const p of diamond.slice(1)) await page.mouse.move(...p, { steps: 12 });
    await page.mouse.up();
    const info = await page.textContent('#sketch-info');
    log(info);
    expect(/points, closed/.test(info) && !/To run/.test(info), `the sketch was not recorded: ${info}`);
    await shot('sketch-drawn.png');
    await page.fill('#sketch-frames', String(opts.frames));
    await page.click('#sketch-run');
    await page.waitForFunction(
      () => /sketch job .* (succeeded|failed|cancelled)/.test(document.getElementById('job-status').textContent),
      null,
      { timeout: jobTimeout, polling: 200 },
    );
    const sent = jobRequests.at(-1);
    log(`sent view ${JSON.stringify(sent.view)}, ${sent.sketch.points.length} points, closed ${sent.sketch.closed}`);
    expect(sent.kind === 'sketch' && sent.tree === a.id && sent.sketch.closed === true, 'the sketch request is not a closed sketch of the viewed tree');
    // A landscape view: the square frame spans the canvas height, with the camera's fov.
    expect(Math.abs(sent.view.fov_deg - 40) < 1e-6, `fov_deg ${sent.view.fov_deg} is not the rendered 40°`);
    const [x0, y0] = sent.sketch.points[0];
    expect(Math.abs(x0) < 0.02 && Math.abs(y0 - 0.84) < 0.02, `the diamond's top, drawn at NDC (0, 0.84), was sent as (${x0}, ${y0})`);
    expect(sent.sketch.points.every(([x, y]) => Math.abs(x) <= 1 && Math.abs(y) <= 1), 'a sketch point lies outside [-1, 1]');
    const sketchStatus = await page.textContent('#job-status');
    expect(/succeeded/.test(sketchStatus), `the sketch job did not succeed: ${sketchStatus}`);
    await page.waitForFunction((n) => Number(document.getElementById('scrub').max) === n - 1, opts.frames, { timeout: 60_000 });
    await page.click('#play');
    if ((await page.getAttribute('#play', 'aria-pressed')) === 'true') await page.click('#play');
    await page.focus('#scrub');
    await page.keyboard.press('End');
    await page.waitForTimeout(200);
    const sketchLast = await shot('sketch-result.png');
    const sketchStats = await pixels(await canvas.screenshot());
    log(`${sketchStatus}; last frame ${(sketchStats.nonBackground * 100).toFixed(1)}% non-background`);
    expect(sketchStats.nonBackground > 0.001, 'the sketch result looks blank');
    void sketchLast;

    begin('checking a narrow window');
    await page.setViewportSize({ width: 420, height: 860 });
    await page.waitForTimeout(300);
    await shot('narrow.png');
    const viewBox = await canvas.boundingBox();
    expect(viewBox && viewBox.width > 300 && viewBox.height > 250, `the view is too small on a narrow window: ${JSON.stringify(viewBox)}`);
    // A portrait view: the sketch frame is the canvas width, its fov narrower than the camera's.
    await page.click('#sketch-clear');
    await page.click('#sketch-toggle');
    await page.waitForTimeout(200);
    const pbox = await page.locator('#sketch-overlay').boundingBox();
    const pside = Math.min(pbox.width, pbox.height);
    const [pcx, pcy] = [pbox.x + pbox.width / 2, pbox.y + pbox.height / 2];
    await page.mouse.move(pcx, pcy - 0.45 * pside);
    await page.mouse.down();
    await page.mouse.move(pcx + 0.45 * pside, pcy + 0.2 * pside, { steps: 5 });
    await page.mouse.move(pcx - 0.45 * pside, pcy + 0.2 * pside, { steps: 5 });
    await page.mouse.up();
    const portrait = await page.evaluate(() => {
      const { view, points } = window.treemorph.pad.sketch;
      const c = document.getElementById('sketch-overlay');
      return { fov: view.fov_deg, first: points[0], w: c.clientWidth, h: c.clientHeight };
    });
    const wantFov = (2 * Math.atan((Math.tan((20 * Math.PI) / 180) * Math.min(portrait.w, portrait.h)) / portrait.h) * 180) / Math.PI;
    log(`portrait ${portrait.w}×${portrait.h}: sketch fov ${portrait.fov.toFixed(3)}° (want ${wantFov.toFixed(3)}°), top point (${portrait.first.map((v) => v.toFixed(3))})`);
    expect(portrait.w < portrait.h && Math.abs(portrait.fov - wantFov) < 1e-9, 'the portrait sketch fov is not the square frame\'s');
    expect(Math.abs(portrait.first[0]) < 0.02 && Math.abs(portrait.first[1] - 0.9) < 0.02, `the top point, drawn at NDC (0, 0.9), was recorded as (${portrait.first})`);
    await shot('narrow-sketch.png');
    await page.keyboard.press('Escape');
    await page.locator('#generate').scrollIntoViewIfNeeded();
    expect(await page.locator('#generate').isVisible(), 'the Generate button cannot be reached on a narrow window');

    const errors = await page.locator('#errors li').allTextContents();
    expect(errors.length === 0, `the page shows errors: ${errors.join(' | ')}`);
    expect(pageErrors.length === 0, pageErrors.join('\n'));
    console.log('browser test passed');
  } catch (e) {
    await shot('failure.png').catch(() => {});
    const errors = await page.locator('#errors li').allTextContents().catch(() => []);
    throw new Error(`${step}: ${e.message}${errors.length ? `\n  errors shown by the page: ${errors.join(' | ')}` : ''}${pageErrors.length ? `\n  ${pageErrors.join('\n  ')}` : ''}${failedUrls.length ? `\n  failed requests: ${failedUrls.join(', ')}` : ''}`);
  } finally {
    await browser.close();
  }
}

main().then(
  () => process.exit(0),
  (e) => {
    console.error(`browser test FAILED at ${e.message}`);
    process.exit(1);
  },
);
