#!/usr/bin/env node
// Writes GLB trees made by a third-party procedural generator, ez-tree
// (npm `@dgreenheck/ez-tree`, pinned in package.json / package-lock.json),
// into the directory given as the first argument. treemorph's importer test
// `third_party` reads them from `TREEMORPH_THIRD_PARTY_DIR`.
//
//   npm ci --prefix tools/third-party-trees
//   node tools/third-party-trees/generate.mjs OUT_DIR
//
// ez-tree builds three.js geometry: every branch a separate tube (a tube
// soup; each child starts inside its parent) and leaves as textured,
// alpha-tested quads (single or crossed billboards). The GLB is written
// here from that geometry (positions, UVs, indices; the leaf texture is the
// PNG ez-tree ships) rather than through three's GLTFExporter, which needs
// a browser canvas to encode textures. Besides the GLB, each tree gets a
// `NAME.json` with the figures the test checks against: branch and leaf
// counts as ez-tree made them.

import fs from 'node:fs';
import path from 'node:path';

// ez-tree loads its textures at import time with three's TextureLoader,
// which needs a DOM image element. A stub records the data URI it is given.
globalThis.document = {
  createElementNS() {
    return {
      style: {},
      addEventListener() {},
      removeEventListener() {},
      set src(value) { this._src = value; },
      get src() { return this._src; },
    };
  },
};

const { Tree } = await import('@dgreenheck/ez-tree');

const out = process.argv[2];
if (!out) {
  console.error('usage: node generate.mjs OUT_DIR');
  process.exit(2);
}
fs.mkdirSync(out, { recursive: true });

// (file name, ez-tree preset, seed, billboard mode, branch overrides).
// The stock presets import as 400–1,900 branches; the overrides add
// children (and for the aspen and pine a level of twigs) so that every
// tree imports with 2,000–15,000 branches, as the acceptance asks.
const TREES = [
  ['ash-large', 'Ash Large', 11, 'double', { children: { 0: 12, 1: 5, 2: 4 } }],
  ['oak-large', 'Oak Large', 7, 'single', { children: { 0: 10, 1: 6, 2: 4 } }],
  ['aspen-large', 'Aspen Large', 3, 'double', { levels: 3, children: { 2: 3 } }],
  ['pine-large', 'Pine Large', 5, 'single', { levels: 2, children: { 1: 2 } }],
  ['bush-1', 'Bush 1', 2, 'double', { children: { 1: 4, 2: 4 } }],
];

function pad4(n) {
  return (4 - (n % 4)) % 4;
}

/** A GLB with a `branches` mesh (opaque bark) and a `leaves` mesh
 *  (alpha-masked, double-sided, textured). */
function glb(tree) {
  const chunks = [];
  const views = [];
  const accessors = [];
  let length = 0;
  const view = (bytes, target) => {
    const offset = length;
    chunks.push(bytes);
    const padding = pad4(bytes.length);
    if (padding) chunks.push(new Uint8Array(padding));
    length += bytes.length + padding;
    views.push({ buffer: 0, byteOffset: offset, byteLength: bytes.length, ...(target ? { target } : {}) });
    return views.length - 1;
  };
  const floats = (list, type, components) => {
    const data = new Float32Array(list);
    const min = new Array(components).fill(Infinity);
    const max = new Array(components).fill(-Infinity);
    for (let i = 0; i < data.length; i++) {
      const c = i % components;
      min[c] = Math.min(min[c], data[i]);
      max[c] = Math.max(max[c], data[i]);
    }
    const v = view(new Uint8Array(data.buffer), 34962);
    accessors.push({ bufferView: v, componentType: 5126, count: data.length / components, type,
      ...(type === 'VEC3' ? { min, max } : {}) });
    return accessors.length - 1;
  };
  const indices = (list) => {
    const data = new Uint32Array(list);
    const v = view(new Uint8Array(data.buffer), 34963);
    accessors.push({ bufferView: v, componentType: 5125, count: data.length, type: 'SCALAR' });
    return accessors.length - 1;
  };

  const b = tree.branches;
  const l = tree.leaves;
  // three.js textures are flipped (v = 0 is the image's bottom row) where
  // glTF's v = 0 is the top row; GLTFExporter flips the image, we flip v.
  const flipV = (uvs) => uvs.map((x, i) => (i % 2 === 1 ? 1 - x : x));
  const branchMesh = {
    name: 'branches',
    primitives: [{
      attributes: { POSITION: floats(b.verts, 'VEC3', 3), TEXCOORD_0: floats(flipV(b.uvs), 'VEC2', 2) },
      indices: indices(b.indices),
      material: 0,
    }],
  };
  const leafMesh = {
    name: 'leaves',
    primitives: [{
      attributes: { POSITION: floats(l.verts, 'VEC3', 3), TEXCOORD_0: floats(flipV(l.uvs), 'VEC2', 2) },
      indices: indices(l.indices),
      material: 1,
    }],
  };

  const materials = [
    { name: 'bark', pbrMetallicRoughness: { baseColorFactor: [0.45, 0.35, 0.25, 1], metallicFactor: 0, roughnessFactor: 0.9 } },
    { name: 'leaves', alphaMode: 'MASK', alphaCutoff: tree.options.leaves.alphaTest, doubleSided: true,
      pbrMetallicRoughness: { baseColorFactor: [1, 1, 1, 1], metallicFactor: 0, roughnessFactor: 0.8 } },
  ];
  const doc = {
    asset: { version: '2.0', generator: 'ez-tree 1.1.0 via treemorph tools/third-party-trees' },
    scene: 0,
    scenes: [{ nodes: [0] }],
    nodes: [{ name: 'tree', children: [1, 2] }, { name: 'branches', mesh: 0 }, { name: 'leaves', mesh: 1 }],
    meshes: [branchMesh, leafMesh],
    materials,
    accessors,
    bufferViews: views,
  };
  const src = tree.leavesMesh.material.map?.image?.src;
  const png = typeof src === 'string' && src.startsWith('data:image/png;base64,')
    ? Buffer.from(src.slice('data:image/png;base64,'.length), 'base64')
    : null;
  if (png) {
    const v = view(new Uint8Array(png), undefined);
    doc.images = [{ bufferView: v, mimeType: 'image/png' }];
    doc.samplers = [{ magFilter: 9729, minFilter: 9987, wrapS: 33071, wrapT: 33071 }];
    doc.textures = [{ sampler: 0, source: 0 }];
    materials[1].pbrMetallicRoughness.baseColorTexture = { index: 0 };
  }
  doc.buffers = [{ byteLength: length }];

  const json = Buffer.from(JSON.stringify(doc));
  const jsonPadded = Buffer.concat([json, Buffer.alloc(pad4(json.length), 0x20)]);
  const bin = Buffer.concat(chunks.map((c) => Buffer.from(c.buffer, c.byteOffset, c.byteLength)));
  const total = 12 + 8 + jsonPadded.length + 8 + bin.length;
  const header = Buffer.alloc(12);
  header.writeUInt32LE(0x46546c67, 0);
  header.writeUInt32LE(2, 4);
  header.writeUInt32LE(total, 8);
  const jsonHeader = Buffer.alloc(8);
  jsonHeader.writeUInt32LE(jsonPadded.length, 0);
  jsonHeader.writeUInt32LE(0x4e4f534a, 4);
  const binHeader = Buffer.alloc(8);
  binHeader.writeUInt32LE(bin.length, 0);
  binHeader.writeUInt32LE(0x004e4942, 4);
  return Buffer.concat([header, jsonHeader, jsonPadded, binHeader, bin]);
}

for (const [name, preset, seed, billboard, branch] of TREES) {
  const tree = new Tree();
  tree.loadPreset(preset);
  if (branch.levels !== undefined) tree.options.branch.levels = branch.levels;
  Object.assign(tree.options.branch.children, branch.children);
  tree.options.seed = seed;
  tree.options.leaves.billboard = billboard;
  tree.generate();
  const bytes = glb(tree);
  fs.writeFileSync(path.join(out, `${name}.glb`), bytes);
  const quads = tree.leaves.indices.length / 6;
  const facts = {
    preset,
    seed,
    branch,
    billboard,
    branch_vertices: tree.branches.verts.length / 3,
    leaf_quads: quads,
    leaves: billboard === 'double' ? quads / 2 : quads,
  };
  fs.writeFileSync(path.join(out, `${name}.json`), JSON.stringify(facts, null, 2) + '\n');
  console.log(`${name}.glb: ${bytes.length} bytes, ${facts.branch_vertices} branch vertices, ${facts.leaves} leaves`);
}
