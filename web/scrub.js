/**
 * @file Scrubbing between received frames. The timeline is continuous:
 * when its cursor rests between two frames of the stream (or on a frame
 * the {@link FrameStore} thinned away), the player shows the nearest kept
 * frame at once and {@link InstantScrubber} asks the server for the
 * instant under the cursor, as a one-frame delta stream with the job's own
 * header (`GET /v1/jobs/{id}/stream?t=`), whose positions drop straight
 * into the player's meshes.
 *
 * - **Latest wins.** At most one request is in flight. Cursor moves while
 *   it runs only replace the instant wanted next, so a drag costs one
 *   render per round trip, and the instant where the drag stops is always
 *   the last one fetched. Every answer is delivered, even one the cursor
 *   has moved past: during a drag a slightly late instant is better than
 *   none.
 * - **Quantised instants.** `t` is rounded to a multiple of 1/4096 (a
 *   4096-frame animation's step; finer than a slider's pixels), so
 *   revisited instants hit the server's render cache and this one.
 * - **A small cache.** The last {@link DEFAULT_CACHE} instants fetched are
 *   kept decoded, least recently used dropped.
 *
 * Nothing here touches the DOM or the network directly: the caller passes
 * the fetch (see `JobRun.instantAt`).
 */

/** Instants are multiples of 1 / INSTANT_STEPS. */
export const INSTANT_STEPS = 4096;

/** Decoded instants kept, by default. */
export const DEFAULT_CACHE = 24;

/** `t` clamped to [0, 1] and rounded to a multiple of 1 / {@link INSTANT_STEPS}. */
export function quantise(t) {
  const c = Math.min(1, Math.max(0, Number(t) || 0));
  return Math.round(c * INSTANT_STEPS) / INSTANT_STEPS;
}

export class InstantScrubber {
  /**
   * @param {(t: number) => Promise<object>} fetchFrame Fetches and decodes
   *   the instant `t` (a decoded frame: `{t, leafBlend, positions}`).
   * @param {object} callbacks
   * @param {(t: number, frame: object) => void} callbacks.onFrame An instant arrived.
   * @param {(error: Error, t: number) => void} [callbacks.onError] A fetch failed.
   * @param {object} [options]
   * @param {number} [options.cacheSize]
   */
  constructor(fetchFrame, { onFrame, onError = () => {} }, { cacheSize = DEFAULT_CACHE } = {}) {
    this.fetchFrame = fetchFrame;
    this.onFrame = onFrame;
    this.onError = onError;
    this.cacheSize = Math.max(1, cacheSize);
    /** @type {Map<number, object>} insertion order = least recently used first */
    this.cache = new Map();
    /** The instant to fetch next (null: none). */
    this.wanted = null;
    /** Whether a fetch is in flight. */
    this.busy = false;
    /** Fetches made (for tests and diagnostics). */
    this.fetches = 0;
    /** Settles when the fetch loop is idle. @type {Promise<void>} */
    this.idle = Promise.resolve();
  }

  /** Asks for instant `t` (quantised); returns the quantised instant. */
  want(t) {
    const q = quantise(t);
    const hit = this.cache.get(q);
    if (hit) {
      this.cache.delete(q);
      this.cache.set(q, hit);
      this.wanted = null;
      this.onFrame(q, hit);
      return q;
    }
    this.wanted = q;
    if (!this.busy) this.idle = this.pump();
    return q;
  }

  /** Forgets the instant wanted next (the cursor went back to a received frame). */
  cancel() {
    this.wanted = null;
  }

  async pump() {
    this.busy = true;
    try {
      while (this.wanted !== null) {
        const t = this.wanted;
        this.wanted = null;
        this.fetches += 1;
        let frame;
        try {
          frame = await this.fetchFrame(t);
        } catch (e) {
          this.onError(e, t);
          continue;
        }
        this.remember(t, frame);
        this.onFrame(t, frame);
      }
    } finally {
      this.busy = false;
    }
  }

  remember(t, frame) {
    this.cache.set(t, frame);
    while (this.cache.size > this.cacheSize) this.cache.delete(this.cache.keys().next().value);
  }
}
