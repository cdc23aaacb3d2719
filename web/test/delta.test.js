// Cross-tests of web/delta.js on the bytes the Rust encoder wrote:
// api/tests/fixtures/small.tmd and the frames it decodes to (small.json,
// written by api/tests/delta_golden.rs), plus the README's worked example.
// Run: npm test --prefix web   (after npm ci --prefix web)

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';

import { Decoder, DeltaError, MEDIA_TYPE, crc32, decodeAll, decodeFramesAt, decodeStream } from '../delta.js';

const fixture = (name) => new URL(`../../api/tests/fixtures/${name}`, import.meta.url);
const stream = new Uint8Array(readFileSync(fixture('small.tmd')));
const expected = JSON.parse(readFileSync(fixture('small.json'), 'utf8'));

/** Exact f32 comparison: JSON holds the f32 values widened to doubles. */
function assertF32(actual, expectedValues, what) {
  assert.equal(actual.length, expectedValues.length, `${what}: length`);
  for (let i = 0; i < actual.length; i++) {
    if (actual[i] !== Math.fround(expectedValues[i])) {
      assert.fail(`${what}[${i}]: ${actual[i]} !== ${expectedValues[i]}`);
    }
  }
}

/** Feeds `bytes` in chunks of the given sizes (cycled); returns the events. */
function decodeChunked(bytes, sizes) {
  const decoder = new Decoder();
  const events = [];
  let at = 0;
  let k = 0;
  while (at < bytes.length) {
    const n = Math.max(1, Math.min(sizes[k++ % sizes.length], bytes.length - at));
    decoder.push(bytes.subarray(at, at + n));
    at += n;
    events.push(...decoder.events());
  }
  events.push(...decoder.events());
  decoder.finish();
  return events;
}

/** A deterministic pseudo-random sequence of chunk sizes. */
function randomSizes(seed, count, max) {
  let s = seed >>> 0;
  const out = [];
  for (let i = 0; i < count; i++) {
    s = (Math.imul(s, 1664525) + 1013904223) >>> 0;
    out.push(1 + (s % max));
  }
  return out;
}

test('the media type and the CRC-32 check value', () => {
  assert.equal(MEDIA_TYPE, 'application/vnd.treemorph.delta');
  assert.equal(crc32(new TextEncoder().encode('123456789')), 0xcbf43926);
});

test('the fixture decodes to the frames the Rust decoder recorded', () => {
  const { header, frames } = decodeAll(stream);
  const want = expected.header;
  assertF32(header.bounds.flat(), want.bounds.flat(), 'bounds');
  assertF32(header.grid.origin, want.grid.origin, 'grid origin');
  assertF32(header.grid.step, want.grid.step, 'grid step');
  assert.equal(header.frameCount, want.frameCount);
  assert.equal(header.textures.length, want.textures.length);
  header.textures.forEach((t, i) => assert.deepEqual([...t.png], want.textures[i].bytes));
  assert.equal(header.materials.length, want.materials.length);
  header.materials.forEach((m, i) => {
    const w = want.materials[i];
    assert.equal(m.name, w.name);
    assertF32(m.baseColor, w.baseColor, `material ${i} colour`);
    assert.equal(m.alphaMode, w.alphaMode);
    assert.equal(m.alphaCutoff, w.alphaCutoff === null ? null : Math.fround(w.alphaCutoff));
    assert.equal(m.doubleSided, w.doubleSided);
    assert.equal(m.texture, w.texture);
  });
  assert.deepEqual(
    header.meshes.map((m) => m.name),
    ['branches', 'leaves'],
  );
  header.meshes.forEach((m, i) => {
    const w = want.meshes[i];
    assert.equal(m.name, w.name);
    assert.deepEqual([...m.indices], w.indices);
    assertF32(m.uvs, w.uvs, `mesh ${i} uvs`);
    assert.deepEqual(m.groups, w.groups);
    assertF32(m.basePositions, w.basePositions, `mesh ${i} base positions`);
    assert.equal(m.vertexCount * 3, m.basePositions.length);
  });
  // The leaf group cross-fades between two leaf materials.
  assert.equal(header.meshes[1].groups[0].fadeTo, 2);

  assert.equal(frames.length, expected.frames.length);
  frames.forEach((f, i) => {
    const w = expected.frames[i];
    assert.equal(f.index, w.index);
    assert.equal(f.t, Math.fround(w.t));
    assert.equal(f.leafBlend, Math.fround(w.leafBlend));
    assert.equal(f.positions.length, w.positions.length);
    f.positions.forEach((p, m) => {
      assert.ok(p instanceof Float32Array);
      assertF32(p, w.positions[m], `frame ${i} mesh ${m}`);
    });
  });
  assert.equal(expected.end.frames, frames.length);
});

test('arbitrary chunk splits give the same events', () => {
  const whole = decodeChunked(stream, [stream.length]);
  assert.equal(whole.length, 1 + expected.frames.length + 1);
  assert.deepEqual(whole.at(-1), { type: 'end', frames: expected.frames.length });
  for (const sizes of [[1], [2, 3, 5], [7], [64], [4096], randomSizes(1, 50, 40), randomSizes(2, 50, 300)]) {
    assert.deepEqual(decodeChunked(stream, sizes), whole, `chunks ${sizes.slice(0, 5)}`);
  }
});

test('decodeStream reads a ReadableStream', async () => {
  const sizes = randomSizes(3, 1000, 100);
  const source = new ReadableStream({
    start(controller) {
      let at = 0;
      for (let k = 0; at < stream.length; k++) {
        const n = Math.min(sizes[k], stream.length - at);
        controller.enqueue(stream.slice(at, at + n));
        at += n;
      }
      controller.close();
    },
  });
  const events = [];
  for await (const e of decodeStream(source)) events.push(e);
  assert.deepEqual(events, decodeChunked(stream, [stream.length]));
});

test('every truncation is reported and keeps the complete frames', () => {
  const whole = decodeChunked(stream, [stream.length]);
  for (let cut = 0; cut < stream.length; cut++) {
    const decoder = new Decoder();
    decoder.push(stream.subarray(0, cut));
    const got = [...decoder.events()];
    assert.deepEqual(got, whole.slice(0, got.length), `cut at ${cut}`);
    assert.throws(
      () => decoder.finish(),
      (e) =>
        e instanceof DeltaError &&
        e.code === 'truncated' &&
        e.offset === cut &&
        e.frames === got.filter((x) => x.type === 'frame').length,
      `cut at ${cut}`,
    );
  }
});

test('every single bit flip is detected', () => {
  for (let byte = 0; byte < stream.length; byte++) {
    for (let bit = 0; bit < 8; bit++) {
      const damaged = stream.slice();
      damaged[byte] ^= 1 << bit;
      assert.throws(
        () => decodeChunked(damaged, [97]),
        DeltaError,
        `flip of bit ${bit} in byte ${byte} went unnoticed`,
      );
    }
  }
  const codeOf = (bytes) => {
    try {
      decodeAll(bytes);
    } catch (e) {
      return e.code;
    }
    return 'ok';
  };
  const flipped = (at) => {
    const d = stream.slice();
    d[at] ^= 0x10;
    return d;
  };
  assert.equal(codeOf(flipped(0)), 'bad_magic');
  assert.equal(codeOf(flipped(4)), 'unsupported_version');
  assert.equal(codeOf(flipped(40)), 'checksum_mismatch');
  assert.equal(codeOf(flipped(stream.length - 6)), 'checksum_mismatch');
});

test('errors are sticky and data after the end is refused', () => {
  const damaged = stream.slice();
  damaged[40] ^= 1;
  const decoder = new Decoder();
  decoder.push(damaged);
  assert.throws(() => decoder.nextEvent(), { code: 'checksum_mismatch' });
  assert.throws(() => decoder.nextEvent(), { code: 'checksum_mismatch' });
  assert.throws(() => decoder.finish(), { code: 'checksum_mismatch' });

  const longer = new Uint8Array(stream.length + 1);
  longer.set(stream);
  assert.throws(() => decodeAll(longer), { code: 'corrupt' });
});

test('declared sizes over the limits are refused', () => {
  assert.throws(() => decodeAll(stream, { maxVertices: 10 }), { code: 'too_large', what: 'vertex count' });
  assert.throws(() => decodeAll(stream, { maxRecordBytes: 100 }), { code: 'too_large' });
});

test("the README's worked example decodes as described", () => {
  const readme = readFileSync(new URL('../../api/README.md', import.meta.url), 'utf8');
  const block = readme.split('```hex\n')[1].split('```')[0];
  const bytes = new Uint8Array(
    block
      .split('\n')
      .flatMap((line) => line.split('#')[0].trim().split(/\s+/))
      .filter(Boolean)
      .map((h) => parseInt(h, 16)),
  );
  assert.equal(bytes.length, 238);
  const { header, frames } = decodeAll(bytes);
  assert.equal(header.meshes[0].name, 't');
  assert.deepEqual([...header.meshes[0].indices], [0, 1, 2]);
  assert.deepEqual([...header.meshes[0].basePositions], [0, 0, 0, 1, 0, 0, 0, 1, 0]);
  assert.equal(frames.length, 1);
  assert.equal(frames[0].t, 1);
  assert.deepEqual([...frames[0].positions[0]], [0, 0, 0, 1, 0, 0.5, 0, 1, 0]);
});

/** FNV-1a (32-bit) of the bytes of a typed array (little-endian platforms). */
function fnv1a(typed) {
  const bytes = new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength);
  let h = 0x811c9dc5;
  for (let i = 0; i < bytes.length; i++) h = Math.imul(h ^ bytes[i], 0x01000193) >>> 0;
  return h;
}

test('the blocks fixture (several blocks, every bit width, zstd) decodes as recorded', () => {
  const bytes = new Uint8Array(readFileSync(fixture('blocks.tmd')));
  const want = JSON.parse(readFileSync(fixture('blocks.json'), 'utf8'));
  const check = (positions, summary, what) => {
    assert.equal(positions.length, 3 * summary.vertices, `${what}: vertices`);
    for (const [i, p] of summary.samples) assertF32(positions.subarray(3 * i, 3 * i + 3), p, `${what} vertex ${i}`);
    assert.equal(fnv1a(positions), summary.fnv1a, `${what}: hash`);
  };
  for (const sizes of [[bytes.length], randomSizes(4, 200, 5000)]) {
    const events = decodeChunked(bytes, sizes);
    const header = events[0].header;
    assert.equal(header.meshes[0].indices.length, want.header.indexCount);
    assert.equal(fnv1a(header.meshes[0].indices), want.header.indicesFnv1a);
    header.meshes.forEach((m, i) => check(m.basePositions, want.header.base[i], `base ${i}`));
    const frames = events.filter((e) => e.type === 'frame').map((e) => e.frame);
    assert.equal(frames.length, want.frames.length);
    frames.forEach((f, i) => {
      assert.equal(f.index, want.frames[i].index);
      assert.equal(f.t, Math.fround(want.frames[i].t));
      assert.equal(f.leafBlend, Math.fround(want.frames[i].leafBlend));
      f.positions.forEach((p, m) => check(p, want.frames[i].positions[m], `frame ${i} mesh ${m}`));
    });
    assert.deepEqual(events.at(-1), { type: 'end', frames: want.frames.length });
  }
});

test('decodeFramesAt continues from a header decoded before, without its bytes', () => {
  const decoder = new Decoder();
  decoder.push(stream);
  const header = decoder.nextEvent();
  assert.equal(header.type, 'header');
  const headerEnd = decoder.offset;
  const frames = [];
  for (let e; (e = decoder.nextEvent()) && e.type === 'frame'; ) frames.push(e.frame);
  const { frames: whole } = decodeAll(stream);
  // The records between the header and the end record.
  const framesEnd = headerEnd + recordsLength(stream, headerEnd, whole.length);
  const again = decodeFramesAt(header.base, stream.subarray(headerEnd, framesEnd));
  assert.deepEqual(again, whole);
  assert.deepEqual(frames, whole, 'the base was taken before the frames and left them alone');
  // The base is copied: decoding from it twice gives the same frames.
  assert.deepEqual(decodeFramesAt(header.base, stream.subarray(headerEnd, framesEnd)), whole);
  assert.throws(() => decodeFramesAt(header.base, stream.subarray(headerEnd)), /end record where only frame records belong/);
  assert.throws(() => decodeFramesAt(header.base, stream.subarray(headerEnd, framesEnd - 1)), (e) => e.code === 'truncated');
});

/** Bytes of the first `n` records from `offset` (prefix: kind, codec, 2 spare, stored length u32, raw length u32; then payload and CRC). */
function recordsLength(bytes, offset, n) {
  let at = offset;
  for (let i = 0; i < n; i++) {
    const view = new DataView(bytes.buffer, bytes.byteOffset + at, 12);
    at += 12 + view.getUint32(4, true) + 4;
  }
  return at - offset;
}
