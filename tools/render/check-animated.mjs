// Checks that three.js plays an animated GLB the way treemorph wrote it.
//
//   node check-animated.mjs FILE.glb EXPECTED.json
//
// Loads FILE.glb with three.js's GLTFLoader in headless Chromium (Debian's
// /usr/bin/chromium, or $CHROMIUM; EXT_meshopt_compression through
// three.js's MeshoptDecoder), plays its first animation with an
// AnimationMixer, seeks it to each sample time and computes the sampled
// vertices' world positions on the CPU from the geometry, its morph
// attributes, the mesh's current morphTargetInfluences, its joints (a
// skinned mesh) and its world matrix — exactly what the vertex shader does. EXPECTED.json (written by
// the treemorph-gltf crate's ignored `threejs` test) gives, per mesh
// (node name), the vertex count, the morph target count and the expected
// positions at a few times:
//
//   { "tolerance": 1e-4,
//     "meshes": [ { "name": "leaves", "vertices": 1234, "morphTargets": 5,
//                   "samples": [ { "time": 0.5, "indices": [0, 17],
//                                  "positions": [[x, y, z], [x, y, z]] } ] } ] }
//
// Prints the load time and an estimate of the GPU memory three.js uses
// for the file, one line per check, and exits 1 on any mismatch (2 on bad
// usage). An EXPECTED.json with no meshes only measures.
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));

const page = `<!doctype html><html><head>
<script type="importmap">{"imports":{"three":"/three/build/three.module.js","three/addons/":"/three/examples/jsm/"}}</script>
</head><body><script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
window.check = async (url, expected) => {
  const loader = new GLTFLoader();
  loader.setMeshoptDecoder(MeshoptDecoder);
  const started = performance.now();
  const gltf = await loader.loadAsync(url);
  const loadMs = performance.now() - started;
  const scene = gltf.scene;
  // What the GPU holds, estimated as three.js r187 uploads it: every
  // buffer attribute once (shared attributes are one upload), and per
  // geometry a float texture of its morph targets with one vec4 per vertex,
  // target and morphed attribute (position, normal, colour).
  const attributes = new Set();
  let morphBytes = 0;
  const geometries = new Set();
  scene.traverse((o) => { if (o.isMesh) geometries.add(o.geometry); });
  for (const g of geometries) {
    for (const a of Object.values(g.attributes)) attributes.add(a);
    if (g.index) attributes.add(g.index);
    const morphed = Object.values(g.morphAttributes).filter((list) => list.length > 0);
    if (morphed.length) morphBytes += g.attributes.position.count * morphed[0].length * morphed.length * 16;
  }
  let attributeBytes = 0;
  for (const a of attributes) attributeBytes += a.array.byteLength;
  const gpu = 'loaded in ' + loadMs.toFixed(0) + ' ms, GPU estimate ' + ((attributeBytes + morphBytes) / 1e6).toFixed(1) +
    ' MB (' + (attributeBytes / 1e6).toFixed(1) + ' MB attributes, ' + (morphBytes / 1e6).toFixed(1) + ' MB morph textures, ' + geometries.size + ' geometries)';
  const clip = gltf.animations[0];
  if (!clip) return { errors: ['the file has no animation'], lines: [] };
  const mixer = new THREE.AnimationMixer(scene);
  // Played once and held at the end, so seeking to the clip's duration
  // shows the last keyframe instead of wrapping around to the first.
  const action = mixer.clipAction(clip);
  action.setLoop(THREE.LoopOnce, 1);
  action.clampWhenFinished = true;
  action.play();
  const errors = [];
  const lines = [gpu];
  const v = new THREE.Vector3();
  const d = new THREE.Vector3();
  for (const want of expected.meshes) {
    // A glTF mesh with several primitives loads as a group of meshes that
    // share one vertex buffer; any of them carries the morphs.
    const node = scene.getObjectByName(want.name);
    let mesh = null;
    node?.traverse((o) => { if (!mesh && o.isMesh) mesh = o; });
    if (!mesh) { errors.push(want.name + ': no mesh'); continue; }
    const geometry = mesh.geometry;
    const position = geometry.attributes.position;
    const morphs = geometry.morphAttributes.position || [];
    lines.push(want.name + ': ' + position.count + ' vertices, ' + morphs.length + ' morph targets, relative ' + geometry.morphTargetsRelative);
    if (position.count !== want.vertices) errors.push(want.name + ': ' + position.count + ' vertices, expected ' + want.vertices);
    if (morphs.length !== want.morphTargets) errors.push(want.name + ': ' + morphs.length + ' morph targets, expected ' + want.morphTargets);
    let worst = 0;
    for (const sample of want.samples) {
      // A clamped action pauses when it reaches the end; seeking again
      // must resume it, or every later seek shows the first frame.
      action.paused = false;
      action.enabled = true;
      mixer.setTime(sample.time);
      scene.updateMatrixWorld(true);
      const influences = mesh.morphTargetInfluences;
      sample.indices.forEach((index, k) => {
        v.fromBufferAttribute(position, index);
        morphs.forEach((morph, m) => {
          const w = influences[m];
          if (w !== 0) {
            d.fromBufferAttribute(morph, index);
            if (geometry.morphTargetsRelative) v.addScaledVector(d, w);
            else v.addScaledVector(d.sub(new THREE.Vector3().fromBufferAttribute(position, index)), w);
          }
        });
        // A skinned mesh: its joints carry the morphed bind position
        // (three.js's own CPU skinning, as its shader does it).
        if (mesh.isSkinnedMesh) mesh.applyBoneTransform(index, v);
        v.applyMatrix4(mesh.matrixWorld);
        const [x, y, z] = sample.positions[k];
        const e = Math.hypot(v.x - x, v.y - y, v.z - z);
        worst = Math.max(worst, e);
        if (!(e <= expected.tolerance)) {
          errors.push(want.name + ' vertex ' + index + ' at ' + sample.time + ' s: (' + v.x + ', ' + v.y + ', ' + v.z + '), expected (' + x + ', ' + y + ', ' + z + ')');
        }
      });
    }
    lines.push(want.name + ': ' + want.samples.length + ' times checked, largest error ' + worst.toExponential(2));
  }
  return { errors: errors.slice(0, 20), lines };
};
window.ready = true;
</script></body></html>`;

function serve(file) {
  const server = http.createServer((req, res) => {
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    if (url === '/') { res.writeHead(200, { 'content-type': 'text/html' }); res.end(page); return; }
    if (url === '/favicon.ico') { res.writeHead(204); res.end(); return; }
    let target = null;
    let type = 'application/octet-stream';
    if (url.startsWith('/three/')) {
      target = path.join(here, 'node_modules', url.slice(1));
      type = 'text/javascript';
    } else if (url === '/file.glb') {
      target = file;
      type = 'model/gltf-binary';
    }
    if (!target || !fs.existsSync(target)) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'content-type': type });
    fs.createReadStream(target).pipe(res);
  });
  return new Promise((resolve) => server.listen(0, '127.0.0.1', () => resolve(server)));
}

async function main() {
  const [file, expectedPath] = process.argv.slice(2);
  if (!file || !expectedPath) {
    console.error('usage: node check-animated.mjs FILE.glb EXPECTED.json');
    process.exit(2);
  }
  const expected = JSON.parse(fs.readFileSync(expectedPath, 'utf8'));
  const server = await serve(file);
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync'],
  });
  let failed = false;
  try {
    const tab = await browser.newPage();
    tab.on('pageerror', (e) => console.error('page error:', e.message));
    tab.on('console', (m) => { if (m.type() === 'error' || m.type() === 'warning') console.error('page', m.type() + ':', m.text()); });
    await tab.goto(`http://127.0.0.1:${server.address().port}/`);
    await tab.waitForFunction(() => window.ready === true);
    const result = await tab.evaluate(([e]) => window.check('/file.glb', e), [expected]);
    for (const line of result.lines) console.log(`${file}: ${line}`);
    for (const error of result.errors) console.log(`${file}: MISMATCH ${error}`);
    failed = result.errors.length > 0;
  } finally {
    await browser.close();
    server.close();
  }
  console.log(`check-animated: ${file}: ${failed ? 'FAILED' : 'ok'}`);
  process.exit(failed ? 1 : 0);
}

main().catch((e) => { console.error(`check-animated: ${e.message}`); process.exit(1); });
