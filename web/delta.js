// Decoder of the treemorph delta stream (application/vnd.treemorph.delta),
// version 1.x. The format is specified byte by byte in api/README.md; the
// Rust crate treemorph-api (module `delta`) is the reference encoder and
// decoder, and web/test/ checks this decoder against the same fixture.
//
// Usage (browser or node):
//
//   import { Decoder } from './delta.js';
//   const decoder = new Decoder();
//   const reader = (await fetch(url)).body.getReader();
//   for (;;) {
//     const { value, done } = await reader.read();
//     if (done) break;
//     decoder.push(value);
//     for (let e; (e = decoder.nextEvent()); ) {
//       if (e.type === 'header') setUp(e.header);
//       else if (e.type === 'frame') show(e.frame); // positions: Float32Array per mesh
//     }
//   }
//   decoder.finish(); // throws DeltaError { code: 'truncated' } if the stream was cut
//
// Or `for await (const e of decodeStream(response.body)) …`.
//
// Normals are not in the stream: recompute them per frame
// (three.js BufferGeometry.computeVertexNormals()).

import { decompress } from 'fzstd';

/** HTTP media type of a delta stream. */
export const MEDIA_TYPE = 'application/vnd.treemorph.delta';
/** The major version this decoder reads. */
export const VERSION_MAJOR = 1;
/** The minor version this decoder knows. */
export const VERSION_MINOR = 0;
/** Grid coordinates stay within ±2^24. */
export const MAX_GRID_COORDINATE = 1 << 24;

const MAGIC = [0x54, 0x4d, 0x44, 0x53]; // "TMDS"
const PREAMBLE_LEN = 8;
const PREFIX_LEN = 12;
const CRC_LEN = 4;
const KIND_HEADER = 0x48;
const KIND_FRAME = 0x46;
const KIND_END = 0x45;
const KIND_ANCILLARY = 0x80;
const CODEC_STORED = 0;
const CODEC_ZSTD = 1;
const NONE = 0xffffffff;
const BLOCK = 4096;
const BLOCK_PREDICT = 0x80;
const BLOCK_BITS = 0x3f;
const WIDTHS = new Set([0, 1, 2, 4, 8, 16, 24, 32]);
const PNG_SIGNATURE = [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a];

/**
 * Limits checked before anything a stream declares is allocated (same
 * defaults as the Rust decoder).
 */
export const DEFAULT_LIMITS = Object.freeze({
  maxMeshes: 16,
  maxVertices: 4_000_000,
  maxIndices: 24_000_000,
  maxGroups: 65_536,
  maxMaterials: 1_024,
  maxTextures: 256,
  maxTextureBytes: 64 * 1024 * 1024,
  maxNameBytes: 1_024,
  maxRecordBytes: 256 * 1024 * 1024,
});

/**
 * A decoding error. `code` is one of `bad_magic`, `unsupported_version`,
 * `truncated`, `checksum_mismatch`, `corrupt`, `too_large`, `frame_order`;
 * `offset` (stream byte offset of the record or of the cut) and `frames`
 * (frames decoded before the problem) are set where they apply.
 */
export class DeltaError extends Error {
  constructor(code, message, details = {}) {
    super(message);
    this.name = 'DeltaError';
    this.code = code;
    Object.assign(this, details);
  }
}

const CRC_TABLE = (() => {
  const table = new Uint32Array(256);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    table[n] = c >>> 0;
  }
  return table;
})();

/** CRC-32/ISO-HDLC of `bytes`, continuing from `crc` (0 to start). */
export function crc32(bytes, crc = 0) {
  let c = ~crc >>> 0;
  for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return ~c >>> 0;
}

function tooLarge(what, size, limit) {
  if (size > limit) {
    throw new DeltaError('too_large', `${what} is ${size}, over the limit of ${limit}`, { what, size, limit });
  }
}

const utf8 = new TextDecoder('utf-8', { fatal: true });

/** Bounded reads from one record payload; errors name the record. */
class Reader {
  constructor(bytes, offset) {
    this.bytes = bytes;
    this.view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    this.pos = 0;
    this.offset = offset;
  }

  corrupt(reason) {
    return new DeltaError('corrupt', `corrupt delta stream in the record at byte ${this.offset}: ${reason}`, {
      offset: this.offset,
      reason,
    });
  }

  get remaining() {
    return this.bytes.length - this.pos;
  }

  need(n) {
    if (n > this.remaining) {
      throw this.corrupt(`payload ends early: ${n} bytes needed at payload byte ${this.pos}, ${this.remaining} left`);
    }
  }

  take(n) {
    this.need(n);
    const out = this.bytes.subarray(this.pos, this.pos + n);
    this.pos += n;
    return out;
  }

  u8() {
    this.need(1);
    return this.bytes[this.pos++];
  }

  u32() {
    this.need(4);
    const v = this.view.getUint32(this.pos, true);
    this.pos += 4;
    return v;
  }

  f32() {
    this.need(4);
    const v = this.view.getFloat32(this.pos, true);
    this.pos += 4;
    return v;
  }

  f32s(n) {
    const out = [];
    for (let i = 0; i < n; i++) out.push(this.f32());
    return out;
  }

  string(limit) {
    const len = this.u32();
    tooLarge('name length', len, limit);
    try {
      return utf8.decode(this.take(len));
    } catch {
      throw this.corrupt('a name is not UTF-8');
    }
  }

  /**
   * Reads one block into `out` (an Int32Array whose length is the block's
   * value count); `before` is the value preceding the block. Returns the
   * block's last value.
   */
  block(out, before) {
    const header = this.u8();
    const bits = header & BLOCK_BITS;
    if (header & 0x40 || !WIDTHS.has(bits)) throw this.corrupt(`invalid block header 0x${header.toString(16)}`);
    const m = out.length;
    const bytes = this.take(Math.ceil((m * bits) / 8));
    if (bits === 0) {
      out.fill(0);
    } else if (bits < 8) {
      const perByte = 8 / bits;
      const mask = (1 << bits) - 1;
      for (let i = 0; i < m; i++) out[i] = (bytes[(i / perByte) | 0] >>> ((i % perByte) * bits)) & mask;
    } else {
      const planes = bits / 8;
      for (let i = 0; i < m; i++) {
        let z = bytes[i];
        for (let k = 1; k < planes; k++) z |= bytes[k * m + i] << (8 * k);
        out[i] = z;
      }
    }
    // Zigzag back to signed, then undo the prediction (wrapping int32).
    if (header & BLOCK_PREDICT) {
      let previous = before;
      for (let i = 0; i < m; i++) {
        const z = out[i];
        previous = (previous + ((z >>> 1) ^ -(z & 1))) | 0;
        out[i] = previous;
      }
    } else {
      for (let i = 0; i < m; i++) {
        const z = out[i];
        out[i] = (z >>> 1) ^ -(z & 1);
      }
    }
    return m > 0 ? out[m - 1] : before;
  }

  /** An integer array of `n` values. */
  array(n) {
    const out = new Int32Array(n);
    let before = 0;
    for (let start = 0; start < n; start += BLOCK) {
      before = this.block(out.subarray(start, Math.min(n, start + BLOCK)), before);
    }
    return out;
  }

  /**
   * Vertex blocks for `n` vertices: calls `apply(axis, start, values)` for
   * each block of values read.
   */
  vertexBlocks(n, scratch, apply) {
    const before = [0, 0, 0];
    for (let start = 0; start < n; start += BLOCK) {
      const values = scratch.subarray(0, Math.min(n, start + BLOCK) - start);
      for (let axis = 0; axis < 3; axis++) {
        before[axis] = this.block(values, before[axis]);
        apply(axis, start, values);
      }
    }
  }
}

/**
 * Checks that `bytes` is exactly one zstd frame that declares `rawLen`
 * bytes of content, without a dictionary (so fzstd allocates no more than
 * `rawLen`), walking the block headers to find the frame's end.
 */
function checkZstdFrame(bytes, rawLen, r) {
  const fail = (why) => r.corrupt(`the payload is not one zstd frame of ${rawLen} bytes (${why})`);
  if (bytes.length < 6 || bytes[0] !== 0x28 || bytes[1] !== 0xb5 || bytes[2] !== 0x2f || bytes[3] !== 0xfd) {
    throw fail('no zstd magic');
  }
  const fhd = bytes[4];
  const fcsFlag = fhd >> 6;
  const singleSegment = (fhd >> 5) & 1;
  const checksum = (fhd >> 2) & 1;
  const dictFlag = fhd & 3;
  if (fhd & 8) throw fail('reserved bit set');
  let pos = 5 + (singleSegment ? 0 : 1);
  const dictBytes = [0, 1, 2, 4][dictFlag];
  for (let i = 0; i < dictBytes; i++) if (bytes[pos + i]) throw fail('dictionary required');
  pos += dictBytes;
  const fcsBytes = fcsFlag === 0 ? singleSegment : 1 << fcsFlag;
  if (fcsBytes === 0) throw fail('content size not declared');
  if (pos + fcsBytes > bytes.length) throw fail('frame header cut');
  let size = 0;
  for (let i = fcsBytes - 1; i >= 0; i--) size = size * 256 + bytes[pos + i];
  if (fcsBytes === 2) size += 256;
  if (size !== rawLen) throw fail(`declares ${size} bytes`);
  pos += fcsBytes;
  for (;;) {
    if (pos + 3 > bytes.length) throw fail('block header cut');
    const b = bytes[pos] | (bytes[pos + 1] << 8) | (bytes[pos + 2] << 16);
    const last = b & 1;
    const type = (b >> 1) & 3;
    const blockSize = b >>> 3;
    if (type === 3) throw fail('reserved block type');
    pos += 3 + (type === 1 ? 1 : blockSize);
    if (pos > bytes.length) throw fail('block cut');
    if (last) break;
  }
  if (checksum) pos += 4;
  if (pos !== bytes.length) throw fail('bytes after the frame');
}

/**
 * Incremental decoder: `push()` bytes in chunks of any size, then call
 * `nextEvent()` until it returns null (more bytes needed). Events:
 * `{ type: 'header', header }` (first), `{ type: 'frame', frame }`,
 * `{ type: 'end', frames }`. At end of input call `finish()`, which throws
 * a DeltaError with code `truncated` unless the stream was complete.
 * Errors are sticky: after one, every call throws it again.
 */
export class Decoder {
  constructor(limits = {}) {
    this.limits = { ...DEFAULT_LIMITS, ...limits };
    this.buf = new Uint8Array(0);
    this.start = 0;
    this.end = 0;
    this.offset = 0; // stream offset of buf[start]
    this.state = 'preamble';
    this.error = null;
    this.minor = 0;
    this.preamble = null;
    this.frames = 0;
    this.header = null;
    this.q = null; // per mesh: [Int32Array x, y, z]
    this.maxFramePayload = 0;
  }

  /** Appends received bytes (a Uint8Array). */
  push(chunk) {
    const length = this.end - this.start;
    if (length + chunk.length > this.buf.length - this.start) {
      if (length + chunk.length > this.buf.length) {
        const grown = new Uint8Array(Math.max(length + chunk.length, this.buf.length * 2, 65536));
        grown.set(this.buf.subarray(this.start, this.end));
        this.buf = grown;
      } else {
        this.buf.copyWithin(0, this.start, this.end);
      }
      this.start = 0;
      this.end = length;
    }
    this.buf.set(chunk, this.end);
    this.end += chunk.length;
  }

  /** Whether the end record has been decoded. */
  get complete() {
    return this.state === 'ended';
  }

  /** The next event, or null when more bytes are needed (or after the end). */
  nextEvent() {
    if (this.error) throw this.error;
    try {
      return this.step();
    } catch (e) {
      this.error =
        e instanceof DeltaError ? e : new DeltaError('corrupt', `corrupt delta stream: ${e.message}`, { cause: e });
      throw this.error;
    }
  }

  /** Every event available now. */
  *events() {
    for (let e; (e = this.nextEvent()); ) yield e;
  }

  /**
   * Declares the end of input; throws unless the stream was complete. Call
   * it once nextEvent() has returned null.
   */
  finish() {
    if (this.error) throw this.error;
    if (this.state === 'ended' && this.end === this.start) return;
    if (this.state === 'ended') {
      throw new DeltaError('corrupt', `corrupt delta stream at byte ${this.offset}: bytes after the end record`, {
        offset: this.offset,
      });
    }
    const offset = this.offset + (this.end - this.start);
    throw new DeltaError(
      'truncated',
      `stream truncated at byte ${offset}, after ${this.frames} complete frames`,
      { offset, frames: this.frames },
    );
  }

  consume(n) {
    this.start += n;
    this.offset += n;
  }

  step() {
    for (;;) {
      const available = this.end - this.start;
      const bytes = this.buf.subarray(this.start, this.end);
      switch (this.state) {
        case 'ended':
          if (available > 0) {
            throw new DeltaError('corrupt', `corrupt delta stream at byte ${this.offset}: bytes after the end record`, {
              offset: this.offset,
            });
          }
          return null;
        case 'preamble': {
          const n = Math.min(available, 4);
          for (let i = 0; i < n; i++) {
            if (bytes[i] !== MAGIC[i]) throw new DeltaError('bad_magic', 'not a treemorph delta stream (bad magic bytes)');
          }
          if (available < PREAMBLE_LEN) return null;
          const major = bytes[4] | (bytes[5] << 8);
          const minor = bytes[6] | (bytes[7] << 8);
          if (major !== VERSION_MAJOR) {
            throw new DeltaError(
              'unsupported_version',
              `unsupported delta stream version ${major}.${minor} (this decoder reads ${VERSION_MAJOR}.x)`,
              { major, minor },
            );
          }
          this.minor = minor;
          this.preamble = bytes.slice(0, PREAMBLE_LEN);
          this.consume(PREAMBLE_LEN);
          this.state = 'header';
          break;
        }
        default: {
          if (available < PREFIX_LEN) return null;
          const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
          const kind = bytes[0];
          const codec = bytes[1];
          const storedLen = view.getUint32(4, true);
          const rawLen = view.getUint32(8, true);
          tooLarge('record size', storedLen, this.limits.maxRecordBytes);
          tooLarge('decompressed record size', rawLen, this.limits.maxRecordBytes);
          const len = PREFIX_LEN + storedLen + CRC_LEN;
          if (available < len) return null;
          const crc = view.getUint32(len - CRC_LEN, true);
          const covered = bytes.subarray(0, len - CRC_LEN);
          const computed = kind === KIND_HEADER ? crc32(covered, crc32(this.preamble)) : crc32(covered);
          if (computed !== crc) {
            throw new DeltaError(
              'checksum_mismatch',
              `checksum mismatch in the record at byte ${this.offset}, after ${this.frames} frames`,
              { offset: this.offset, frames: this.frames },
            );
          }
          const r0 = new Reader(new Uint8Array(0), this.offset);
          if (kind === KIND_FRAME && this.minor <= VERSION_MINOR && this.state === 'frames' && rawLen > this.maxFramePayload) {
            throw r0.corrupt(`a frame payload of ${rawLen} bytes is larger than any frame of this header`);
          }
          const stored = bytes.subarray(PREFIX_LEN, PREFIX_LEN + storedLen);
          let raw;
          if (codec === CODEC_STORED) {
            if (rawLen !== storedLen) throw r0.corrupt(`stored payload of ${storedLen} bytes declares ${rawLen} bytes`);
            raw = stored;
          } else if (codec === CODEC_ZSTD) {
            checkZstdFrame(stored, rawLen, r0);
            try {
              raw = decompress(stored);
            } catch (e) {
              throw r0.corrupt(`zstd: ${e.message}`);
            }
            if (raw.length !== rawLen) throw r0.corrupt(`zstd payload decompressed to ${raw.length} bytes, not ${rawLen}`);
          } else {
            throw r0.corrupt(`unknown codec ${codec}`);
          }
          const event = this.parse(kind, new Reader(raw, this.offset));
          this.consume(len);
          if (event) return event;
        }
      }
    }
  }

  parse(kind, r) {
    if (kind === KIND_HEADER && this.state === 'header') {
      const header = this.parseHeader(r);
      this.state = 'frames';
      return { type: 'header', header, base: this.base() };
    }
    if (kind === KIND_FRAME && this.state === 'frames') return { type: 'frame', frame: this.parseFrame(r) };
    if (kind === KIND_END && this.state === 'frames') {
      const frames = r.u32();
      if (frames !== this.frames) throw r.corrupt(`the end record counts ${frames} frames but ${this.frames} were sent`);
      if (this.header.frameCount !== 0 && frames !== this.header.frameCount) {
        throw r.corrupt(`the header announced ${this.header.frameCount} frames but the stream has ${frames}`);
      }
      this.checkTrailing(r);
      this.state = 'ended';
      return { type: 'end', frames };
    }
    if (kind & KIND_ANCILLARY) return null;
    if (kind === KIND_HEADER || kind === KIND_FRAME || kind === KIND_END) {
      throw r.corrupt(`record kind '${String.fromCharCode(kind)}' out of place`);
    }
    throw r.corrupt(`unknown record kind 0x${kind.toString(16)}`);
  }

  checkTrailing(r) {
    if (r.remaining > 0 && this.minor <= VERSION_MINOR) {
      throw r.corrupt(`${r.remaining} unexpected bytes at the end of a record`);
    }
  }

  parseHeader(r) {
    const L = this.limits;
    const b = r.f32s(6);
    const bounds = [b.slice(0, 3), b.slice(3, 6)];
    const grid = { origin: r.f32s(3), step: r.f32s(3) };
    const frameCount = r.u32();

    const textureCount = r.u32();
    tooLarge('texture count', textureCount, L.maxTextures);
    const textures = [];
    let textureBytes = 0;
    for (let i = 0; i < textureCount; i++) {
      const len = r.u32();
      textureBytes += len;
      tooLarge('texture bytes', textureBytes, L.maxTextureBytes);
      const png = r.take(len).slice();
      if (!PNG_SIGNATURE.every((v, k) => png[k] === v)) throw r.corrupt(`texture ${i} is not a PNG`);
      textures.push({ png });
    }

    const materialCount = r.u32();
    tooLarge('material count', materialCount, L.maxMaterials);
    const materials = [];
    for (let i = 0; i < materialCount; i++) {
      const name = r.string(L.maxNameBytes);
      const baseColor = r.f32s(4);
      const mode = r.u8();
      const cutoff = r.f32();
      const sided = r.u8();
      const texture = r.u32();
      if (mode > 2) throw r.corrupt(`unknown alpha mode ${mode}`);
      if (sided > 1) throw r.corrupt(`double-sided flag ${sided} is not 0 or 1`);
      if (!baseColor.every((c) => c >= 0 && c <= 1)) throw r.corrupt(`material ${i}: base colour outside [0, 1]`);
      if (mode === 1 && !(cutoff >= 0 && cutoff <= 1)) throw r.corrupt(`material ${i}: alpha cutoff outside [0, 1]`);
      if (texture !== NONE && texture >= textureCount) throw r.corrupt(`material ${i}: texture ${texture} does not exist`);
      materials.push({
        name,
        baseColor,
        alphaMode: ['opaque', 'mask', 'blend'][mode],
        alphaCutoff: mode === 1 ? cutoff : null,
        doubleSided: sided === 1,
        texture: texture === NONE ? null : texture,
      });
    }

    const meshCount = r.u32();
    tooLarge('mesh count', meshCount, L.maxMeshes);
    const meshes = [];
    this.q = [];
    let vertices = 0;
    let indicesTotal = 0;
    let groupsTotal = 0;
    let maxPayload = 12;
    for (let m = 0; m < meshCount; m++) {
      const name = r.string(L.maxNameBytes);
      const n = r.u32();
      const indexCount = r.u32();
      const groupCount = r.u32();
      vertices += n;
      indicesTotal += indexCount;
      groupsTotal += groupCount;
      tooLarge('vertex count', vertices, L.maxVertices);
      tooLarge('index count', indicesTotal, L.maxIndices);
      tooLarge('material group count', groupsTotal, L.maxGroups);
      const groups = [];
      for (let g = 0; g < groupCount; g++) {
        const first = r.u32();
        const count = r.u32();
        const material = r.u32();
        const fade = r.u32();
        if (first % 3 || count % 3 || first + count > indexCount) {
          throw r.corrupt(`mesh ${m} group ${g} is not a whole-triangle range of the ${indexCount} indices`);
        }
        for (const ref of [material, fade === NONE ? 0 : fade]) {
          if (ref >= materialCount) throw r.corrupt(`mesh ${m} group ${g}: material ${ref} does not exist`);
        }
        groups.push({ first, count, material, fadeTo: fade === NONE ? null : fade });
      }
      if (indexCount % 3) throw r.corrupt(`mesh ${m}: ${indexCount} indices is not a whole number of triangles`);
      const indices = new Uint32Array(r.array(indexCount).buffer);
      for (let i = 0; i < indexCount; i++) {
        if (indices[i] >= n) throw r.corrupt(`mesh ${m}: index ${i} (${indices[i]}) is out of range for ${n} vertices`);
      }
      const uvBytes = r.take(n * 8);
      const uvView = new DataView(uvBytes.buffer, uvBytes.byteOffset, uvBytes.byteLength);
      const uvs = new Float32Array(2 * n);
      for (let i = 0; i < 2 * n; i++) uvs[i] = uvView.getFloat32(4 * i, true);
      if (!uvs.every(Number.isFinite)) throw r.corrupt(`mesh ${m}: a UV is not finite`);
      const q = [new Int32Array(n), new Int32Array(n), new Int32Array(n)];
      r.vertexBlocks(n, new Int32Array(Math.min(n, BLOCK)), (axis, start, values) => {
        for (let i = 0; i < values.length; i++) {
          const v = values[i];
          if (v > MAX_GRID_COORDINATE || v < -MAX_GRID_COORDINATE) throw r.corrupt('a base grid coordinate is out of range');
          q[axis][start + i] = v;
        }
      });
      this.q.push(q);
      meshes.push({ name, vertexCount: n, indices, uvs, groups, basePositions: null });
      maxPayload += 3 * (1 + Math.ceil(n / BLOCK) + 4 * n);
    }
    this.checkTrailing(r);
    const [min, max] = bounds;
    for (let a = 0; a < 3; a++) {
      if (!(Number.isFinite(min[a]) && Number.isFinite(max[a]) && min[a] <= max[a])) throw r.corrupt('bounds are not finite and ordered');
      if (!Number.isFinite(grid.origin[a])) throw r.corrupt('grid origin is not finite');
      if (!(Number.isFinite(grid.step[a]) && grid.step[a] > 0)) throw r.corrupt('grid step is not finite and positive');
    }
    this.header = { bounds, grid, frameCount, textures, materials, meshes };
    this.maxFramePayload = maxPayload;
    meshes.forEach((mesh, m) => {
      mesh.basePositions = this.positions(m);
    });
    return this.header;
  }

  /**
   * The decoder's state right after the header (its base grid
   * coordinates copied): {@link decodeFramesAt} continues from it.
   */
  base() {
    return {
      limits: this.limits,
      minor: this.minor,
      preamble: this.preamble,
      header: this.header,
      maxFramePayload: this.maxFramePayload,
      q: this.q.map((axes) => axes.map((a) => a.slice())),
    };
  }

  /** Positions of mesh `m` from the grid coordinates, as the spec defines. */
  positions(m) {
    const [xs, ys, zs] = this.q[m];
    const { origin, step } = this.header.grid;
    const out = new Float32Array(3 * xs.length);
    const [ox, oy, oz] = origin;
    const [sx, sy, sz] = step;
    for (let i = 0, j = 0; i < xs.length; i++, j += 3) {
      // Float32Array stores round to f32: p = f32(origin + f32(q * step)).
      out[j] = ox + Math.fround(xs[i] * sx);
      out[j + 1] = oy + Math.fround(ys[i] * sy);
      out[j + 2] = oz + Math.fround(zs[i] * sz);
    }
    return out;
  }

  parseFrame(r) {
    const index = r.u32();
    if (index !== this.frames) {
      throw new DeltaError('frame_order', `frame ${index} where frame ${this.frames} was expected`, {
        expected: this.frames,
        found: index,
      });
    }
    const t = r.f32();
    const leafBlend = r.f32();
    if (!(t >= 0 && t <= 1) || !(leafBlend >= 0 && leafBlend <= 1)) {
      throw r.corrupt(`frame ${index}: t = ${t} or leaf blend ${leafBlend} outside [0, 1]`);
    }
    let scratch = new Int32Array(0);
    for (const q of this.q) {
      const n = q[0].length;
      if (scratch.length < Math.min(n, BLOCK)) scratch = new Int32Array(Math.min(n, BLOCK));
      r.vertexBlocks(n, scratch, (axis, start, values) => {
        const target = q[axis];
        for (let i = 0; i < values.length; i++) {
          const v = target[start + i] + values[i];
          if (v > MAX_GRID_COORDINATE || v < -MAX_GRID_COORDINATE) {
            throw r.corrupt(`frame ${index}: a grid coordinate is out of range`);
          }
          target[start + i] = v;
        }
      });
    }
    this.checkTrailing(r);
    this.frames += 1;
    return { index, t, leafBlend, positions: this.q.map((_, m) => this.positions(m)) };
  }
}

/**
 * Decodes a stream from a ReadableStream (e.g. `response.body`) or any
 * async iterable of Uint8Array chunks, yielding events as they complete;
 * throws a DeltaError if the stream is cut or damaged.
 */
export async function* decodeStream(source, limits = {}) {
  const decoder = new Decoder(limits);
  const iterable =
    typeof source.getReader === 'function'
      ? {
          async *[Symbol.asyncIterator]() {
            const reader = source.getReader();
            try {
              for (;;) {
                const { value, done } = await reader.read();
                if (done) return;
                yield value;
              }
            } finally {
              reader.releaseLock();
            }
          },
        }
      : source;
  for await (const chunk of iterable) {
    decoder.push(chunk);
    yield* decoder.events();
  }
  yield* decoder.events();
  decoder.finish();
}

/**
 * Decodes frame records that follow a header decoded before — `base` is
 * the `base` of that header event — without its bytes: e.g. the frame
 * record of `GET /v1/jobs/{id}/stream?t=T&header=false`
 * (`application/vnd.treemorph.delta-frame`), encoded against the job's
 * own stream header. Returns the frames; throws a DeltaError when the
 * bytes are not whole frame records.
 */
export function decodeFramesAt(base, bytes) {
  const decoder = new Decoder(base.limits);
  Object.assign(decoder, {
    state: 'frames',
    minor: base.minor,
    preamble: base.preamble,
    header: base.header,
    maxFramePayload: base.maxFramePayload,
    q: base.q.map((axes) => axes.map((a) => a.slice())),
  });
  decoder.push(bytes);
  const frames = [];
  for (const e of decoder.events()) {
    if (e.type !== 'frame') throw new DeltaError('corrupt', `a ${e.type} record where only frame records belong`);
    frames.push(e.frame);
  }
  if (decoder.end !== decoder.start) {
    throw new DeltaError('truncated', `frame records truncated after ${frames.length} frames`, { frames: frames.length });
  }
  return frames;
}

/** Decodes a whole stream held in memory: `{ header, frames }`. */
export function decodeAll(bytes, limits = {}) {
  const decoder = new Decoder(limits);
  decoder.push(bytes);
  let header = null;
  const frames = [];
  for (const e of decoder.events()) {
    if (e.type === 'header') header = e.header;
    else if (e.type === 'frame') frames.push(e.frame);
  }
  decoder.finish();
  return { header, frames };
}
