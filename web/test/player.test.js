// The stream player fed from the committed delta fixtures
// (api/tests/fixtures/*.tmd, written by the Rust encoder), in node: the
// geometry it builds from the header, the positions and leaf blend it shows
// per frame, the frame store's thinning and the playback clock.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';

import { decodeAll, Decoder } from '../delta.js';
import { FrameStore, Playback, StreamPlayer } from '../player.js';

const fixture = (name) => new URL(`../../api/tests/fixtures/${name}`, import.meta.url);
const small = new Uint8Array(readFileSync(fixture('small.tmd')));
const smallJson = JSON.parse(readFileSync(fixture('small.json'), 'utf8'));
const blocks = new Uint8Array(readFileSync(fixture('blocks.tmd')));

/** Feeds a whole stream through a player, as the viewer does. */
function play(bytes, options = {}) {
  const player = new StreamPlayer({ loadTexture: null, ...options });
  const decoder = new Decoder();
  decoder.push(bytes);
  for (const e of decoder.events()) player.handle(e);
  decoder.finish();
  return player;
}

test('the header becomes one geometry per non-empty mesh with its indices, UVs and groups', () => {
  const player = play(small);
  assert.deepEqual(player.meshes.map((m) => m.name), ['branches', 'leaves']);
  const [branches, leaves] = player.meshes.map((m) => m.geometry);
  const want = smallJson.header.meshes;
  assert.deepEqual([...branches.index.array], want[0].indices);
  assert.deepEqual([...leaves.index.array], want[1].indices);
  assert.equal(leaves.attributes.uv.count, want[1].uvs.length / 2);
  assert.equal(branches.attributes.position.count, want[0].basePositions.length / 3);
  // The bark group is drawn once; the cross-fading leaf group twice (from + to).
  assert.deepEqual(branches.groups.map((g) => [g.start, g.count]), [[0, 48]]);
  assert.deepEqual(leaves.groups.map((g) => [g.start, g.count, g.materialIndex]), [[0, 12, 0], [0, 12, 1]]);
  const leafMaterials = player.meshes[1].mesh.material;
  assert.deepEqual(leafMaterials.map((m) => m.name), ['leaf-green', 'leaf-red']);
  assert.equal(leafMaterials[0].alphaTest, Math.fround(smallJson.header.materials[1].alphaCutoff));
  // Normals are computed (the stream has none) and the bounds cover the animation.
  assert.ok(branches.attributes.normal, 'normals');
  const box = player.bounds();
  assert.deepEqual(box.min.toArray(), [-0.5, 0, -0.5]);
  assert.ok(box.containsBox(branches.boundingBox));
});

test('every frame shows exactly the decoded positions and leaf blend', () => {
  const player = play(small);
  assert.equal(player.received, smallJson.frames.length);
  assert.ok(player.complete);
  for (const want of smallJson.frames) {
    const shown = player.show(want.index);
    assert.equal(shown.index, want.index);
    assert.equal(player.blend.value, Math.fround(want.leafBlend));
    player.meshes.forEach(({ geometry }, m) => {
      const got = geometry.attributes.position.array;
      const expected = want.positions[m];
      assert.equal(got.length, expected.length);
      for (let i = 0; i < got.length; i++) assert.equal(got[i], Math.fround(expected[i]), `frame ${want.index} mesh ${m} [${i}]`);
    });
  }
});

test('the dissolve draws that would discard everything are hidden at the ends of a cross-fade', () => {
  const player = play(small);
  const [from, to] = player.meshes[1].mesh.material;
  player.show(0); // leaf blend 0: only the "from" material
  assert.equal(from.visible, true);
  assert.equal(to.visible, false);
  player.show(2); // 0.25: both
  assert.equal(from.visible && to.visible, true);
  player.show(4); // 1: only the "to" material
  assert.equal(from.visible, false);
  assert.equal(to.visible, true);
  // Both dissolve materials compile to different programs.
  assert.notEqual(from.customProgramCacheKey(), to.customProgramCacheKey());
});

test('the dissolve patch inserts the complementary tests into the standard shader', () => {
  const player = play(small);
  const [from, to] = player.meshes[1].mesh.material;
  for (const [m, cmp] of [[from, 'tmH < tmLeafBlend'], [to, 'tmH >= tmLeafBlend']]) {
    const shader = { uniforms: {}, fragmentShader: 'void main() {\n#include <clipping_planes_fragment>\n}' };
    m.onBeforeCompile(shader);
    assert.equal(shader.uniforms.tmLeafBlend, player.blend);
    assert.match(shader.fragmentShader, /^uniform float tmLeafBlend;/);
    assert.ok(shader.fragmentShader.includes(cmp), cmp);
    assert.ok(shader.fragmentShader.includes(`TM_DISSOLVE == 1`));
    assert.equal(m.defines.TM_DISSOLVE, m === from ? 1 : 2);
  }
});

test('frames arriving one by one are playable before the stream ends', () => {
  const player = new StreamPlayer({ loadTexture: null });
  const decoder = new Decoder();
  const seen = [];
  for (let i = 0; i < small.length; i += 7) {
    decoder.push(small.subarray(i, i + 7));
    for (const e of decoder.events()) {
      player.handle(e);
      if (e.type === 'frame') seen.push(player.show(player.received - 1).index);
    }
  }
  decoder.finish();
  assert.deepEqual(seen, [0, 1, 2, 3, 4]);
});

test('the blocks fixture (9,025 vertices, an empty mesh) plays', () => {
  const { frames } = decodeAll(blocks);
  const player = play(blocks);
  assert.equal(player.meshes.length, 1, 'the empty leaves mesh is skipped');
  const last = player.show(frames.length - 1);
  assert.deepEqual([...player.meshes[0].geometry.attributes.position.array], [...frames.at(-1).positions[0]]);
  assert.equal(last.index, frames.length - 1);
});

test('a small memory budget thins kept frames but always keeps the newest', () => {
  const player = play(blocks, { memoryBudget: 2.5 * (9025 * 12 + 64) });
  const { frames } = decodeAll(blocks);
  assert.ok(player.store.thinned);
  assert.equal(player.received, frames.length);
  assert.equal(player.show(frames.length - 1).index, frames.length - 1);
  assert.equal(player.show(1).index, 0, 'frame 1 was dropped: show the one before');
});

test('FrameStore keeps powers-of-two strides within its capacity', () => {
  const store = new FrameStore(100, 400); // 4 frames
  for (let i = 0; i < 37; i++) store.add({ index: i });
  assert.equal(store.count, 37);
  assert.ok(store.kept.size <= 4);
  assert.equal(store.stride, 16);
  assert.deepEqual([...store.kept.keys()].sort((a, b) => a - b), [0, 16, 32]);
  assert.equal(store.get(36).index, 36);
  assert.equal(store.get(35).index, 32);
  assert.equal(store.get(15).index, 0);
  assert.equal(store.get(99).index, 36, 'clamped to the newest');
  assert.equal(new FrameStore(1, 10).get(0), null);
});

test('Playback waits at the live edge, then loops once complete', () => {
  const p = new Playback({ fps: 10 });
  assert.equal(p.tick(0.1, 0, false), null);
  p.playing = true;
  assert.equal(p.tick(0.25, 3, false), 2); // 2.5 frames in, capped at frame 2
  assert.equal(p.tick(0.5, 3, false), 2); // still waiting for frame 3
  assert.equal(p.tick(0.1, 5, false), 3);
  assert.equal(p.tick(0.15, 5, true), 4);
  assert.equal(p.tick(0.1, 5, true), 0, 'wrapped'); // 4 + 1.0 ... ≥ 5 → loops
  assert.ok(p.playing);
});

// Regression (the browser test's 1-in-4 hang): when playback caught up
// with the newest frame before the stream ended, it was held there and,
// once complete, ticks shorter than a frame (60 Hz at 24 fps) were clamped
// back each time, so it never looped.
test('Playback at the live edge loops once complete, with ticks shorter than a frame', () => {
  const p = new Playback({ fps: 24 });
  p.playing = true;
  for (let i = 0; i < 60; i++) p.tick(1 / 60, 12, false); // caught up, waiting
  assert.equal(p.tick(1 / 60, 12, false), 11);
  const shown = new Set();
  for (let i = 0; i < 120; i++) shown.add(p.tick(1 / 60, 12, true));
  assert.ok(shown.has(0) && shown.has(5), `looped: ${[...shown].sort((a, b) => a - b)}`);
  assert.ok(p.playing);
});

test('Playback without loop stops at the last frame; seek moves the position', () => {
  const p = new Playback({ fps: 24, loop: false });
  p.playing = true;
  assert.equal(p.tick(10, 12, true), 11);
  assert.equal(p.playing, false);
  p.seek(3.7);
  assert.equal(p.tick(1, 12, true), 3, 'paused: no advance');
  p.seek(50);
  assert.equal(p.tick(0, 12, true), 11);
  p.seek(-2);
  assert.equal(p.tick(0, 12, true), 0);
});

test('an instant decoded with a fitting header is shown in the player’s meshes; a misfit is refused', () => {
  const player = play(small);
  const { header, frames } = decodeAll(small);
  const last = frames[frames.length - 1];
  player.show(0);
  assert.ok(player.fits(header));
  assert.ok(player.showInstant(header, last));
  assert.equal(player.shown, -2, 'no stream frame is on screen');
  assert.equal(player.blend.value, last.leafBlend);
  player.meshes.forEach(({ geometry }, m) => {
    assert.deepEqual([...geometry.attributes.position.array], [...last.positions[m]]);
  });
  // Back to a stream frame: its positions are copied again.
  player.show(0);
  player.meshes.forEach(({ geometry }, m) => {
    assert.deepEqual([...geometry.attributes.position.array], [...frames[0].positions[m]]);
  });
  const other = decodeAll(blocks).header;
  assert.equal(player.fits(other), false);
  assert.equal(player.showInstant(other, last), false);
  assert.equal(player.shown, 0, 'a misfit changed the picture');
});
