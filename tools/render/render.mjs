// Renders GLB files to PNG with three.js in headless Chromium.
//
//   node render.mjs [--size WxH] [--view front|side|top|three-quarter]
//                   [--time T] [--frames N] --out OUT.png FILE.glb
//   node render.mjs [options] --out-dir DIR FILE.glb [FILE.glb ...]
//
// --time T renders an animated GLB at T seconds; --frames N renders N
// evenly spaced instants of its first animation side by side into one strip.
// Chromium is Debian's (/usr/bin/chromium, or $CHROMIUM); three.js comes
// from this folder's node_modules.
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));

function parseArgs(argv) {
  const opts = { size: [640, 640], view: 'three-quarter', time: null, frames: 0, out: null, outDir: null, files: [] };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => {
      if (i + 1 >= argv.length) throw new Error(`${a} needs a value`);
      return argv[++i];
    };
    if (a === '--size') opts.size = next().split('x').map(Number);
    else if (a === '--view') opts.view = next();
    else if (a === '--time') opts.time = Number(next());
    else if (a === '--frames') opts.frames = Number(next());
    else if (a === '--out') opts.out = next();
    else if (a === '--out-dir') opts.outDir = next();
    else if (a.startsWith('--')) throw new Error(`unknown option ${a}`);
    else opts.files.push(a);
  }
  if (opts.files.length === 0) throw new Error('no GLB files given');
  if (!opts.out && !opts.outDir) throw new Error('give --out FILE.png or --out-dir DIR');
  if (opts.out && opts.files.length > 1) throw new Error('--out takes one file; use --out-dir for several');
  return opts;
}

const page = `<!doctype html><html><head><style>html,body{margin:0;background:#fff}</style>
<script type="importmap">{"imports":{"three":"/three/build/three.module.js","three/addons/":"/three/examples/jsm/"}}</script>
</head><body><script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
window.renderGlb = async (url, opts) => {
  const [w, h] = opts.size;
  const cols = Math.max(1, opts.frames || 1);
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setSize(w * cols, h);
  renderer.setClearColor(0xffffff, 1);
  renderer.setScissorTest(true);
  document.body.innerHTML = '';
  document.body.appendChild(renderer.domElement);
  const gltf = await new GLTFLoader().setMeshoptDecoder(MeshoptDecoder).loadAsync(url);
  const scene = new THREE.Scene();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x6b5a3a, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 2.2);
  sun.position.set(3, 10, 6);
  scene.add(sun);
  scene.add(gltf.scene);
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const clip = gltf.animations[0];
  if (clip) mixer.clipAction(clip).play();
  const times = [];
  // A looping clip wraps at its duration: sample the last instant just before.
  if (opts.frames && clip) for (let i = 0; i < cols; i++) times.push(Math.min(clip.duration * i / Math.max(1, cols - 1), clip.duration * 0.9999));
  else times.push(opts.time ?? 0);
  // Frame the union of the bounds at every instant so a strip keeps one scale.
  const box = new THREE.Box3();
  for (const t of times) { mixer.setTime(t); gltf.scene.updateMatrixWorld(true); box.union(new THREE.Box3().setFromObject(gltf.scene, true)); }
  const size = box.getSize(new THREE.Vector3());
  const center = box.getCenter(new THREE.Vector3());
  const radius = 0.5 * Math.max(size.x, size.y, size.z);
  const camera = new THREE.PerspectiveCamera(35, w / h, radius * 0.01, radius * 20);
  const dir = { front: [0, 0, 1], side: [1, 0, 0], top: [0, 1, 0.001], 'three-quarter': [0.8, 0.25, 1] }[opts.view] || [0.8, 0.25, 1];
  const d = new THREE.Vector3(...dir).normalize();
  const dist = radius / Math.sin(THREE.MathUtils.degToRad(35) / 2) * 1.05;
  camera.position.copy(center).addScaledVector(d, dist);
  camera.lookAt(center);
  times.forEach((t, i) => {
    mixer.setTime(t);
    renderer.setViewport(i * w, 0, w, h);
    renderer.setScissor(i * w, 0, w, h);
    renderer.render(scene, camera);
  });
  let vertices = 0;
  gltf.scene.traverse(o => { if (o.isMesh) vertices += o.geometry.attributes.position.count; });
  return { vertices, animations: gltf.animations.length };
};
window.ready = true;
</script></body></html>`;

function serve(files) {
  const server = http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    let file = null;
    let type = 'application/octet-stream';
    if (url === '/') { res.writeHead(200, { 'content-type': 'text/html' }); res.end(page); return; }
    if (url.startsWith('/three/')) {
      file = path.join(here, 'node_modules', url.slice(1));
      type = 'text/javascript';
    } else if (url.startsWith('/glb/')) {
      file = files[Number(url.slice(5))];
      type = 'model/gltf-binary';
    }
    if (!file || !fs.existsSync(file)) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'content-type': type });
    fs.createReadStream(file).pipe(res);
  });
  return new Promise(resolve => server.listen(0, '127.0.0.1', () => resolve(server)));
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const server = await serve(opts.files);
  const port = server.address().port;
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
  try {
    const tab = await browser.newPage();
    tab.on('pageerror', e => console.error('page error:', e.message));
    await tab.goto(`http://127.0.0.1:${port}/`);
    await tab.waitForFunction(() => window.ready === true);
    for (let i = 0; i < opts.files.length; i++) {
      const info = await tab.evaluate(([url, o]) => window.renderGlb(url, o), [`/glb/${i}`, opts]);
      const out = opts.out || path.join(opts.outDir, path.basename(opts.files[i]).replace(/\.glb$/i, '') + '.png');
      fs.mkdirSync(path.dirname(path.resolve(out)), { recursive: true });
      await tab.locator('canvas').screenshot({ path: out });
      console.log(`${out}: ${info.vertices} vertices, ${info.animations} animations`);
    }
  } finally {
    await browser.close();
    server.close();
  }
}

main().catch(e => { console.error(`render: ${e.message}`); process.exit(1); });
