/**
 * @file Plays a delta stream (`application/vnd.treemorph.delta`, decoded by
 * `delta.js`) with three.js while it arrives.
 *
 * - {@link StreamPlayer} turns the stream's header into one
 *   `BufferGeometry` per mesh (`branches`, `leaves`) with the header's
 *   indices, UVs and material groups, keeps the decoded frames, and shows
 *   any of them by copying its positions into the geometry and recomputing
 *   normals (the stream sends none).
 * - {@link FrameStore} keeps frames for scrubbing within a memory budget:
 *   a long animation of a big tree would not fit (300,000 vertices × 600
 *   frames × 12 bytes is 2 GB), so past the budget it keeps every 2nd
 *   frame, then every 4th…, and scrubbing shows the nearest kept frame.
 *   The newest frame is always kept, so live playback never lags.
 * - {@link Playback} is the clock: frames per second, play/pause, loop,
 *   and "wait at the live edge" while frames are still streaming.
 * - Leaf cross-fades (groups with `fade_to`) use the complementary dithered
 *   dissolve of api/README.md: the group is drawn twice from the same
 *   vertices, and a per-pixel threshold `h` (interleaved gradient noise of
 *   the screen position, identical in both draws) decides which of the two
 *   materials a pixel shows — `material` where `h ≥ blend`, `fade_to` where
 *   `h < blend`. No sorting, no popping, no double-darkened overlaps; a
 *   small `onBeforeCompile` patch adds the test to MeshStandardMaterial.
 *
 * Everything but texture decoding runs in node too (the tests feed the
 * committed fixtures through it).
 */

import * as THREE from 'three';

/** Bytes of decoded frames kept for scrubbing, by default. */
export const DEFAULT_MEMORY_BUDGET = 768 * 1024 * 1024;

/**
 * Keeps decoded frames within a byte budget, thinning by powers of two.
 */
export class FrameStore {
  /**
   * @param {number} bytesPerFrame Size of one frame's positions.
   * @param {number} [budget] Bytes to spend at most (at least two frames are kept).
   */
  constructor(bytesPerFrame, budget = DEFAULT_MEMORY_BUDGET) {
    this.capacity = Math.max(2, Math.floor(budget / Math.max(1, bytesPerFrame)));
    /** Keep frames whose index is a multiple of this. */
    this.stride = 1;
    /** @type {Map<number, object>} */
    this.kept = new Map();
    /** The newest frame (kept even when the stride skips it). */
    this.latest = null;
    /** Frames received so far. */
    this.count = 0;
  }

  /** Adds the next frame (frames arrive in order). */
  add(frame) {
    this.count = frame.index + 1;
    this.latest = frame;
    if (frame.index % this.stride !== 0) return;
    this.kept.set(frame.index, frame);
    while (this.kept.size > this.capacity) {
      this.stride *= 2;
      for (const i of [...this.kept.keys()]) if (i % this.stride !== 0) this.kept.delete(i);
    }
  }

  /** Whether thinning dropped frames. */
  get thinned() {
    return this.stride > 1;
  }

  /** The frame to show for index `i`: `i` itself, or the nearest kept one before it. */
  get(i) {
    if (this.count === 0) return null;
    i = Math.max(0, Math.min(this.count - 1, Math.floor(i)));
    if (this.latest && i === this.latest.index) return this.latest;
    for (let k = i - (i % this.stride); k >= 0; k -= this.stride) {
      const f = this.kept.get(k);
      if (f) return f;
    }
    return this.latest;
  }
}

/**
 * The playback clock. `position` is a fractional frame index; the stream
 * frame shown is its floor (a paused timeline between frames shows the
 * instant itself, see `scrub.js`).
 */
export class Playback {
  /**
   * @param {object} [options]
   * @param {number} [options.fps] Frames per second (default 24).
   * @param {boolean} [options.loop] Start over at the end (default true).
   */
  constructor({ fps = 24, loop = true } = {}) {
    this.fps = fps;
    this.loop = loop;
    this.playing = false;
    this.position = 0;
  }

  /** Jumps to position `i`, a fractional frame index (scrubbing). */
  seek(i) {
    this.position = Math.max(0, Number(i) || 0);
  }

  /**
   * Advances by `dt` seconds and returns the frame to show, or null when
   * there are none yet. While the stream is incomplete, playback waits at
   * the newest frame instead of looping; once complete it loops (or stops
   * at the end when `loop` is off).
   * @param {number} dt Seconds since the last tick.
   * @param {number} available Frames received.
   * @param {boolean} complete Whether the stream has ended.
   */
  tick(dt, available, complete) {
    if (available === 0) return null;
    const last = available - 1;
    if (this.playing) {
      this.position += Math.max(0, dt) * this.fps;
      if (complete && this.position >= available) {
        if (this.loop && available > 1) {
          this.position %= available;
        } else {
          this.position = last;
          this.playing = false;
        }
      }
    }
    // Waiting at the live edge holds the clock on the newest frame. Once
    // complete it may run on past it (the last frame shows for one frame
    // time, then the wrap above loops): clamping it back to `last` there
    // would undo every tick shorter than a frame and never loop.
    if (this.position >= available || (!complete && this.position > last)) this.position = last;
    return Math.floor(this.position);
  }
}

const DISSOLVE_FROM = 1;
const DISSOLVE_TO = 2;

/**
 * Patches `material` for the dithered dissolve: it keeps the pixels where
 * the threshold is `≥ blend` (`mode` DISSOLVE_FROM) or `< blend`
 * (DISSOLVE_TO). `blend` is a uniform object shared by every material of a
 * player, so one assignment per frame updates them all.
 */
function addDissolve(material, mode, blend) {
  material.defines = { ...(material.defines || {}), TM_DISSOLVE: mode };
  material.onBeforeCompile = (shader) => {
    shader.uniforms.tmLeafBlend = blend;
    shader.fragmentShader = `uniform float tmLeafBlend;\n${shader.fragmentShader}`.replace(
      '#include <clipping_planes_fragment>',
      `#include <clipping_planes_fragment>
      {
        // Interleaved gradient noise (Jimenez 2014): a well spread threshold
        // in [0, 1) that is the same for both draws of a pixel.
        float tmH = fract(52.9829189 * fract(dot(gl_FragCoord.xy, vec2(0.06711056, 0.00583715))));
        #if TM_DISSOLVE == ${DISSOLVE_FROM}
          if (tmH < tmLeafBlend) discard;
        #else
          if (tmH >= tmLeafBlend) discard;
        #endif
      }`,
    );
  };
  material.customProgramCacheKey = () => `tm-dissolve-${mode}`;
}

/**
 * Decodes a PNG into a three.js texture (browser only; glTF UV convention,
 * so no vertical flip).
 * @param {Uint8Array} png
 * @returns {Promise<THREE.Texture>}
 */
export async function loadPngTexture(png) {
  const bitmap = await createImageBitmap(new Blob([png], { type: 'image/png' }), {
    premultiplyAlpha: 'none',
    colorSpaceConversion: 'none',
  });
  const texture = new THREE.Texture(bitmap);
  texture.colorSpace = THREE.SRGBColorSpace;
  texture.flipY = false;
  texture.wrapS = THREE.RepeatWrapping;
  texture.wrapT = THREE.RepeatWrapping;
  texture.anisotropy = 4;
  texture.needsUpdate = true;
  return texture;
}

/**
 * Builds and animates the meshes of one delta stream.
 */
export class StreamPlayer {
  /**
   * @param {object} [options]
   * @param {((png: Uint8Array) => Promise<THREE.Texture>)|null} [options.loadTexture]
   *   Texture decoder (null: untextured, e.g. in node).
   * @param {number} [options.memoryBudget] See {@link FrameStore}.
   */
  constructor({ loadTexture = loadPngTexture, memoryBudget = DEFAULT_MEMORY_BUDGET } = {}) {
    this.loadTexture = loadTexture;
    this.memoryBudget = memoryBudget;
    /** Everything the player draws; add it to the scene. */
    this.group = new THREE.Group();
    this.group.name = 'treemorph-stream';
    this.header = null;
    /** @type {{name: string, geometry: THREE.BufferGeometry, mesh: THREE.Mesh}[]} */
    this.meshes = [];
    /** @type {FrameStore|null} */
    this.store = null;
    this.complete = false;
    /** The shared leaf-blend uniform. */
    this.blend = { value: 0 };
    /** Index of the frame on screen (-1: the header's base positions). */
    this.shown = -1;
    /** Materials by `${index}:${mode}`. @type {Map<string, THREE.Material>} */
    this.materials = new Map();
    /** Textures being decoded (settled when all are applied). @type {Promise<void>} */
    this.texturesReady = Promise.resolve();
  }

  /** Frames received so far. */
  get received() {
    return this.store ? this.store.count : 0;
  }

  /** Frames the animation will have (0 until known). */
  get total() {
    if (this.complete) return this.received;
    return this.header ? this.header.frameCount : 0;
  }

  /** The animation's bounds as a Box3 (null before the header). */
  bounds() {
    if (!this.header) return null;
    const [min, max] = this.header.bounds;
    return new THREE.Box3(new THREE.Vector3(...min), new THREE.Vector3(...max));
  }

  /**
   * Consumes one decoder event (`header`, `frame` or `end`).
   * @returns {string} The event type.
   */
  handle(event) {
    if (event.type === 'header') {
      this.setUp(event.header);
      /** The decoder's state after the header, for instants between frames (`decodeFramesAt`). */
      this.base = event.base || null;
    }
    else if (event.type === 'frame') this.store.add(event.frame);
    else if (event.type === 'end') this.complete = true;
    return event.type;
  }

  /** The material for header material `index` in dissolve `mode` (0 = none). */
  material(index, mode) {
    const key = `${index}:${mode}`;
    let m = this.materials.get(key);
    if (m) return m;
    const spec = this.header.materials[index];
    const [r, g, b, a] = spec.baseColor;
    m = new THREE.MeshStandardMaterial({
      name: spec.name,
      color: new THREE.Color().setRGB(r, g, b, THREE.LinearSRGBColorSpace),
      opacity: a,
      roughness: 0.85,
      metalness: 0,
      side: spec.doubleSided ? THREE.DoubleSide : THREE.FrontSide,
    });
    if (spec.alphaMode === 'mask') m.alphaTest = spec.alphaCutoff ?? 0.5;
    if (spec.alphaMode === 'blend') {
      m.transparent = true;
      m.depthWrite = false;
    }
    if (mode !== 0) addDissolve(m, mode, this.blend);
    m.userData.dissolve = mode;
    this.materials.set(key, m);
    return m;
  }

  /** Builds the geometries and materials from the header. */
  setUp(header) {
    this.header = header;
    let vertices = 0;
    for (const mesh of header.meshes) vertices += mesh.vertexCount;
    this.store = new FrameStore(vertices * 12 + 64, this.memoryBudget);
    const box = this.bounds();
    const sphere = box.getBoundingSphere(new THREE.Sphere());
    for (const spec of header.meshes) {
      if (spec.vertexCount === 0 || spec.indices.length === 0) continue;
      const geometry = new THREE.BufferGeometry();
      const index =
        spec.vertexCount <= 65536 ? new Uint16Array(spec.indices) : new Uint32Array(spec.indices);
      geometry.setIndex(new THREE.BufferAttribute(index, 1));
      const position = new THREE.BufferAttribute(new Float32Array(spec.basePositions), 3);
      position.setUsage(THREE.DynamicDrawUsage);
      geometry.setAttribute('position', position);
      geometry.setAttribute('uv', new THREE.BufferAttribute(spec.uvs, 2));
      const materials = [];
      const slot = (material) => {
        let i = materials.indexOf(material);
        if (i < 0) i = materials.push(material) - 1;
        return i;
      };
      for (const g of spec.groups) {
        if (g.count === 0) continue;
        if (g.fadeTo === null) {
          geometry.addGroup(g.first, g.count, slot(this.material(g.material, 0)));
        } else {
          geometry.addGroup(g.first, g.count, slot(this.material(g.material, DISSOLVE_FROM)));
          geometry.addGroup(g.first, g.count, slot(this.material(g.fadeTo, DISSOLVE_TO)));
        }
      }
      geometry.computeVertexNormals();
      // The header's bounds hold every frame, so culling never needs a recompute.
      geometry.boundingBox = box.clone();
      geometry.boundingSphere = sphere.clone();
      const mesh = new THREE.Mesh(geometry, materials);
      mesh.name = spec.name;
      this.group.add(mesh);
      this.meshes.push({ name: spec.name, geometry, mesh });
    }
    this.applyBlend(0);
    if (this.loadTexture) this.texturesReady = this.loadTextures();
  }

  async loadTextures() {
    const textures = await Promise.all(
      this.header.textures.map((t) =>
        this.loadTexture(t.png).catch((e) => {
          console.warn('a stream texture could not be decoded', e);
          return null;
        }),
      ),
    );
    for (const [key, m] of this.materials) {
      const spec = this.header.materials[Number(key.split(':')[0])];
      const texture = spec.texture === null ? null : textures[spec.texture];
      if (texture) {
        m.map = texture;
        m.needsUpdate = true;
      }
    }
    this.textures = textures.filter(Boolean);
  }

  /** Sets the leaf blend and hides the dissolve draws that would discard everything. */
  applyBlend(blend) {
    this.blend.value = blend;
    for (const m of this.materials.values()) {
      if (m.userData.dissolve === DISSOLVE_FROM) m.visible = blend < 1;
      else if (m.userData.dissolve === DISSOLVE_TO) m.visible = blend > 0;
    }
  }

  /**
   * Shows frame `i` (or the nearest kept one); returns the frame shown, or
   * null when no frame has arrived.
   */
  show(i) {
    const frame = this.store ? this.store.get(i) : null;
    if (!frame) return null;
    if (frame.index !== this.shown) {
      this.copyPositions(frame.positions);
      this.shown = frame.index;
    }
    this.applyBlend(frame.leafBlend);
    return frame;
  }

  /**
   * Whether a frame decoded with `header` (e.g. one instant fetched with
   * `stream?t=`) fits this player's meshes: the same meshes with the same
   * vertex and index counts.
   */
  fits(header) {
    if (!this.header || !header || header.meshes.length !== this.header.meshes.length) return false;
    return header.meshes.every((m, k) => {
      const own = this.header.meshes[k];
      return m.name === own.name && m.vertexCount === own.vertexCount && m.indices.length === own.indices.length;
    });
  }

  /**
   * Shows a frame that is not in the stream (an instant between its
   * frames, decoded with a header that {@link StreamPlayer.fits}); returns
   * false, showing nothing, when it does not fit.
   */
  showInstant(header, frame) {
    if (!this.fits(header)) return false;
    this.copyPositions(frame.positions);
    this.shown = -2; // no stream frame: the next show(i) copies again
    this.applyBlend(frame.leafBlend);
    return true;
  }

  /** Puts per-header-mesh positions into the geometries (empty meshes have none) and recomputes normals. */
  copyPositions(positions) {
    let m = 0;
    for (let k = 0; k < this.header.meshes.length; k++) {
      const spec = this.header.meshes[k];
      if (spec.vertexCount === 0 || spec.indices.length === 0) continue;
      const { geometry } = this.meshes[m++];
      geometry.attributes.position.array.set(positions[k]);
      geometry.attributes.position.needsUpdate = true;
      geometry.computeVertexNormals();
    }
  }

  /** Frees GPU resources. */
  dispose() {
    for (const { geometry } of this.meshes) geometry.dispose();
    for (const m of this.materials.values()) m.dispose();
    for (const t of this.textures || []) t.dispose();
    this.group.clear();
  }
}
