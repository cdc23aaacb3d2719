/**
 * @file The playback bar: play/pause, a timeline over the frames received
 * so far, frames per second and loop. It owns the {@link Playback} clock
 * and shows the player's frame on every viewer tick.
 *
 * Scrubbing pauses playback (the user wants to look at *that* moment).
 * The timeline is continuous: between two received frames (or on a frame
 * the player's memory budget thinned away) it shows the nearest kept
 * frame at once, then the instant under the cursor once the server has
 * rendered it (`scrub.js`; only for a job that succeeded, the server
 * renders no instants before). Arrow keys step one frame, Home and End go
 * to the ends, and Space or K toggles play while the bar has focus.
 */

import { Playback } from './player.js';
import { InstantScrubber, quantise } from './scrub.js';

/** Positions closer than this to a whole frame index are that frame. */
const ON_FRAME = 1e-6;

export class Timeline {
  /**
   * @param {object} els
   * @param {HTMLButtonElement} els.play
   * @param {HTMLInputElement} els.scrub
   * @param {HTMLOutputElement} els.label
   * @param {HTMLInputElement} els.fps
   * @param {HTMLInputElement} els.loop
   * @param {HTMLElement} els.bar The container (for keyboard shortcuts).
   * @param {import('./viewer.js').Viewer} viewer
   */
  constructor(els, viewer) {
    this.els = els;
    this.playback = new Playback({ fps: Number(els.fps.value) || 24, loop: els.loop.checked });
    /** @type {import('./player.js').StreamPlayer|null} */
    this.player = null;
    this.shownFrame = -1;
    /** A frame was put into the geometry outside a tick (scrubbing): draw it on the next tick. */
    this.pendingRender = false;
    /** @type {InstantScrubber|null} Fetches instants between frames (a succeeded job only). */
    this.instants = null;
    /** The instant under the paused cursor when it is between frames (quantised), else null. */
    this.instant = null;
    /** The instant on screen, if one is. */
    this.shownInstant = null;
    /** Why the last instant could not be shown, if it could not. */
    this.instantError = null;
    els.play.addEventListener('click', () => this.setPlaying(!this.playback.playing));
    els.scrub.addEventListener('input', () => this.scrubTo(Number(els.scrub.value)));
    els.scrub.addEventListener('keydown', (e) => this.stepKey(e));
    els.fps.addEventListener('change', () => {
      const fps = Math.max(1, Math.min(120, Number(els.fps.value) || 24));
      els.fps.value = String(fps);
      this.playback.fps = fps;
    });
    els.loop.addEventListener('change', () => {
      this.playback.loop = els.loop.checked;
    });
    els.bar.addEventListener('keydown', (e) => {
      if ((e.key === ' ' || e.key === 'k') && e.target !== els.fps && e.target.tagName !== 'BUTTON') {
        e.preventDefault();
        this.setPlaying(!this.playback.playing);
      }
    });
    viewer.onTick((dt) => this.tick(dt));
    this.refresh();
  }

  /** Plays `player` from its first frame (null: nothing to play). */
  attach(player) {
    this.player = player;
    this.instants = null;
    this.leaveInstant();
    this.playback.seek(0);
    this.shownFrame = -1;
    this.setPlaying(!!player);
    this.refresh();
  }

  /**
   * Lets the timeline show instants between frames, fetched with
   * `fetchInstant(t)` (resolving to `{header, frame}`, see
   * `JobRun.instantAt`); null turns it off.
   */
  setInstantSource(fetchInstant) {
    this.instants = fetchInstant
      ? new InstantScrubber(fetchInstant, {
          onFrame: (t, got) => this.showInstant(t, got),
          onError: (e, t) => {
            this.instantError = e;
            if (this.instant === t) this.update(false);
          },
        })
      : null;
    this.requestInstant();
  }

  setPlaying(playing) {
    this.playback.playing = playing && !!this.player;
    if (this.playback.playing) this.leaveInstant();
    this.els.play.textContent = this.playback.playing ? 'Pause' : 'Play';
    this.els.play.setAttribute('aria-pressed', String(this.playback.playing));
    this.els.play.setAttribute('aria-label', this.playback.playing ? 'Pause the animation' : 'Play the animation');
  }

  /** Pauses at position `p` (a fractional frame index) and shows it. */
  scrubTo(p) {
    this.setPlaying(false);
    this.playback.seek(p);
    this.update(true);
    this.requestInstant();
  }

  /** Arrow keys step one whole frame (a range with `step="any"` would move 1 % of it). */
  stepKey(e) {
    const delta = { ArrowLeft: -1, ArrowDown: -1, ArrowRight: 1, ArrowUp: 1 }[e.key];
    if (!delta || !this.player || this.player.received === 0) return;
    e.preventDefault();
    const p = this.playback.position;
    const next = delta > 0 ? Math.floor(p + ON_FRAME) + 1 : Math.ceil(p - ON_FRAME) - 1;
    this.scrubTo(Math.max(0, Math.min(this.player.received - 1, next)));
  }

  /** Updates the range's extent after frames arrive (or a new player). */
  refresh() {
    const received = this.player ? this.player.received : 0;
    const { scrub, play } = this.els;
    scrub.disabled = received === 0;
    play.disabled = !this.player;
    scrub.max = String(Math.max(0, received - 1));
    this.update(false);
  }

  /** Viewer tick: advance the clock and show its frame; true when the picture changed. */
  tick(dt) {
    if (!this.player) return false;
    const before = this.playback.playing;
    const frame = this.playback.tick(dt, this.player.received, this.player.complete);
    if (before !== this.playback.playing) this.setPlaying(this.playback.playing);
    if (frame !== null && frame !== this.shownFrame && this.instant === null) this.update(true);
    const render = this.pendingRender;
    this.pendingRender = false;
    return render;
  }

  /** The stream frame kept for index `i`, if it is kept exactly. */
  keptFrame(i) {
    const f = this.player && this.player.store ? this.player.store.get(i) : null;
    return f && f.index === i ? f : null;
  }

  /** The instant of fractional frame index `p`: between its frames' own instants. */
  instantOf(p) {
    const n = this.player.total || this.player.received;
    const at = (k) => {
      const f = this.keptFrame(k);
      return f ? f.t : k / Math.max(1, n - 1);
    };
    const i = Math.floor(p);
    const f = p - i;
    return f < ON_FRAME ? at(i) : at(i) + f * (at(i + 1) - at(i));
  }

  /** Asks for the instant under the paused cursor when no kept frame is exactly there. */
  requestInstant() {
    const p = this.playback.position;
    const i = Math.round(p);
    const onFrame = Math.abs(p - i) < ON_FRAME && this.keptFrame(i);
    if (!this.instants || !this.player || this.playback.playing || onFrame || this.player.received < 2) {
      this.leaveInstant();
      this.update(false);
      return;
    }
    this.instantError = null;
    this.instant = quantise(this.instantOf(p));
    this.update(false);
    this.instants.want(this.instant);
  }

  /** Back to stream frames: forget the instant (a late answer is not shown). */
  leaveInstant() {
    if (this.instants) this.instants.cancel();
    this.instant = null;
    this.instantError = null;
    if (this.shownInstant !== null) {
      this.shownInstant = null;
      this.shownFrame = -2; // the geometry holds no stream frame
    }
  }

  /** An instant arrived: shown while the cursor is still between frames. */
  showInstant(t, { header, frame }) {
    if (this.instant === null || this.playback.playing || !this.player) return;
    if (!this.player.showInstant(header, frame)) {
      this.instantError = new Error('the instant does not fit the stream’s meshes');
      this.update(false);
      return;
    }
    this.shownInstant = t;
    this.shownFrame = -2;
    this.pendingRender = true;
    this.update(false);
  }

  /** Shows the clock's frame; returns whether it changed. */
  update(show) {
    const { scrub, label } = this.els;
    if (!this.player || this.player.received === 0) {
      label.value = this.player && this.player.header ? 'waiting for frames…' : '–';
      scrub.value = '0';
      return false;
    }
    const i = Math.min(Math.floor(this.playback.position + ON_FRAME), this.player.received - 1);
    let changed = false;
    if (show && i !== this.shownFrame) {
      const frame = this.player.show(i);
      this.shownFrame = i;
      this.shownInstant = null;
      changed = !!frame;
      if (changed) this.pendingRender = true;
    }
    scrub.value = String(this.playback.playing ? i : Math.min(this.playback.position, this.player.received - 1));
    label.value = this.describe(i);
    scrub.setAttribute('aria-valuetext', label.value);
    return changed;
  }

  /** The label: the frame, or the instant between frames and whether it is on screen yet. */
  describe(i) {
    const total = this.player.total || '?';
    const streaming = this.player.complete ? '' : ` (${this.player.received} received)`;
    // Past the memory budget only every stride-th frame is kept; say so rather than silently repeat frames.
    const thinned = this.player.store.thinned ? ` · every ${this.player.store.stride}th frame kept` : '';
    if (this.instant === null) return `frame ${i + 1} / ${total}${streaming}${thinned}`;
    const t = `t ${this.instant.toFixed(4)}`;
    let state = '';
    if (this.instantError) state = ` · frame ${i + 1} shown (instant unavailable: ${this.instantError.message})`;
    else if (this.shownInstant !== this.instant) state = ` · rendering… (frame ${i + 1} shown)`;
    return `${t} · after frame ${i + 1} / ${total}${streaming}${state}`;
  }
}
