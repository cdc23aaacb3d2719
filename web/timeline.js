/**
 * @file The playback bar: play/pause, a timeline over the frames received
 * so far, frames per second and loop. It owns the {@link Playback} clock
 * and shows the player's frame on every viewer tick.
 *
 * Scrubbing pauses playback (the user wants to look at *that* frame);
 * Space or K toggles play while the bar has focus, and the range input
 * gives arrow keys, Home and End for free.
 */

import { Playback } from './player.js';

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
    els.play.addEventListener('click', () => this.setPlaying(!this.playback.playing));
    els.scrub.addEventListener('input', () => {
      this.setPlaying(false);
      this.playback.seek(Number(els.scrub.value));
      this.update(true);
    });
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
    this.playback.seek(0);
    this.shownFrame = -1;
    this.setPlaying(!!player);
    this.refresh();
  }

  setPlaying(playing) {
    this.playback.playing = playing && !!this.player;
    this.els.play.textContent = this.playback.playing ? 'Pause' : 'Play';
    this.els.play.setAttribute('aria-pressed', String(this.playback.playing));
    this.els.play.setAttribute('aria-label', this.playback.playing ? 'Pause the animation' : 'Play the animation');
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
    if (frame !== null && frame !== this.shownFrame) this.update(true);
    const render = this.pendingRender;
    this.pendingRender = false;
    return render;
  }

  /** Shows the clock's frame; returns whether it changed. */
  update(show) {
    const { scrub, label } = this.els;
    if (!this.player || this.player.received === 0) {
      label.value = this.player && this.player.header ? 'waiting for frames…' : '–';
      scrub.value = '0';
      return false;
    }
    const i = Math.min(Math.floor(this.playback.position), this.player.received - 1);
    let changed = false;
    if (show && i !== this.shownFrame) {
      const frame = this.player.show(i);
      this.shownFrame = i;
      changed = !!frame;
      if (changed) this.pendingRender = true;
    }
    scrub.value = String(i);
    const total = this.player.total || '?';
    const streaming = this.player.complete ? '' : ` (${this.player.received} received)`;
    // Past the memory budget only every stride-th frame is kept; say so rather than silently repeat frames.
    const thinned = this.player.store.thinned ? ` · every ${this.player.store.stride}th frame kept` : '';
    label.value = `frame ${i + 1} / ${total}${streaming}${thinned}`;
    scrub.setAttribute('aria-valuetext', label.value);
    return changed;
  }
}
