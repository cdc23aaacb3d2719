/**
 * @file Runs one job from the browser: starts it, follows its progress
 * (Server-Sent Events) and plays its delta stream while it runs.
 *
 * The two connections are independent on purpose:
 * - **events** (`/v1/jobs/{id}/events`) drive the progress bar, the stage
 *   names and the final state. If the connection drops before a terminal
 *   event, it reconnects (the server opens every connection with a `job`
 *   event holding the present, so nothing is missed).
 * - **stream** (`/v1/jobs/{id}/stream`) feeds the decoder and the player.
 *   It is opened at once — the server holds it until the header exists.
 *   If it ends cut short (`truncated`) the job decides what that means:
 *   still running → a retry replaced the attempt, so start over with a new
 *   player; succeeded → fetch the complete stream; failed or cancelled →
 *   keep the frames already shown (the job's own error is reported by the
 *   events side).
 *
 * Nothing here touches the DOM: callbacks tell the UI what happened.
 */

import { ApiError, TERMINAL_STATUSES } from './api.js';
import { DeltaError, decodeFramesAt, decodeStream } from './delta.js';
import { StreamPlayer } from './player.js';

/** How many times in a row a dropped connection is retried. */
const MAX_RECONNECTS = 8;

const sleep = (ms, signal) =>
  new Promise((resolve) => {
    const t = setTimeout(resolve, ms);
    signal?.addEventListener('abort', () => {
      clearTimeout(t);
      resolve();
    });
  });

/**
 * @typedef {object} JobCallbacks
 * @property {(job: object) => void} [onJob] A (new) job document.
 * @property {(stage: string, progress: number) => void} [onStage]
 * @property {(progress: number) => void} [onProgress]
 * @property {(index: number) => void} [onFrameReady] Frame `index` was published.
 * @property {(player: StreamPlayer) => void} [onPlayer] A new player (first, or after a restart).
 * @property {(type: string, player: StreamPlayer) => void} [onStreamEvent] header / frame / end decoded.
 * @property {(error: Error, context: string) => void} [onError] Something the user must see.
 * @property {(job: object) => void} [onEnd] The job reached a terminal status.
 */

export class JobRun {
  /**
   * @param {import('./api.js').Api} api
   * @param {JobCallbacks} callbacks
   * @param {object} [options]
   * @param {object} [options.playerOptions] Passed to each StreamPlayer.
   */
  constructor(api, callbacks, { playerOptions = {} } = {}) {
    this.api = api;
    this.cb = callbacks;
    this.playerOptions = playerOptions;
    this.abort = new AbortController();
    this.request = null;
    this.job = null;
    this.player = null;
    /** Resolves when both the events and the stream side have finished. */
    this.done = null;
  }

  emit(name, ...args) {
    const f = this.cb[name];
    if (f) f(...args);
  }

  /** Starts the job described by `request`; resolves to the accepted job document. */
  async start(request) {
    /** What was asked for (the sketch view is needed to show the result from it). */
    this.request = request;
    const job = await this.api.createJob(request);
    this.job = job;
    this.emit('onJob', job);
    this.done = Promise.all([this.followEvents(), this.followStream()]);
    return job;
  }

  /** Whether the job has ended. */
  get finished() {
    return !!this.job && TERMINAL_STATUSES.includes(this.job.status);
  }

  /** Asks the server to cancel the job. */
  async cancel() {
    if (!this.job) return;
    const job = await this.api.cancelJob(this.job.id);
    if (job && job.id) this.setJob(job);
  }

  /** Stops following the job (the job itself goes on); used when another job replaces it. */
  detach() {
    this.abort.abort();
  }

  setJob(job) {
    const wasFinished = this.finished;
    this.job = job;
    this.emit('onJob', job);
    if (!wasFinished && this.finished) this.emit('onEnd', job);
  }

  /**
   * Applies an incremental event to the job document. The events carry no
   * status: progress of any kind means a worker holds the job, so a
   * `queued` job is `running` from then on.
   */
  patch(fields) {
    if (this.finished) return;
    const status = this.job.status === 'queued' ? 'running' : this.job.status;
    this.job = { ...this.job, ...fields, status };
    this.emit('onJob', this.job);
  }

  async followEvents() {
    const signal = this.abort.signal;
    let failures = 0;
    while (!signal.aborted && !this.finished) {
      try {
        for await (const { event, data } of this.api.jobEvents(this.job.id, signal)) {
          failures = 0;
          if (event === 'job' || event === 'done' || event === 'failed' || event === 'cancelled') {
            if (data && data.id) this.setJob(data);
          } else if (event === 'stage') {
            this.patch({ stage: data.stage, progress: data.progress });
            this.emit('onStage', data.stage, data.progress);
          } else if (event === 'progress') {
            this.patch({ progress: data.progress });
            this.emit('onProgress', data.progress);
          } else if (event === 'frame') {
            this.patch({ frames_ready: Math.max(this.job.frames_ready || 0, data.index + 1) });
            this.emit('onFrameReady', data.index);
          }
          if (this.finished) return;
        }
      } catch (e) {
        if (signal.aborted) return;
        // 4xx other than 408/429 will not get better by retrying.
        if (e instanceof ApiError && e.status >= 400 && e.status < 500 && e.status !== 408 && e.status !== 429) {
          this.emit('onError', e, 'following the job');
          return;
        }
        failures += 1;
        if (failures > MAX_RECONNECTS) {
          this.emit('onError', e, 'following the job');
          return;
        }
      }
      if (signal.aborted || this.finished) return;
      // The connection ended early: read the job (it may have ended) and reconnect.
      await sleep(Math.min(500 * 2 ** failures, 8000), signal);
      try {
        this.setJob(await this.api.getJob(this.job.id, signal));
      } catch (e) {
        if (signal.aborted) return;
        failures += 1;
        if (failures > MAX_RECONNECTS) {
          this.emit('onError', e, 'following the job');
          return;
        }
      }
    }
  }

  /**
   * The instant `t` in [0, 1] of a succeeded job, for the current player:
   * the server renders its frame record against the job's own stream
   * header (`stream?t=&header=false`), which the player holds, and it is
   * decoded from the player's base. Resolves to `{header, frame}` (see
   * scrub.js).
   */
  async instantAt(t, signal) {
    const player = this.player;
    if (!player || !player.base) throw new Error('no stream header to decode the instant with');
    const response = await this.api.jobStreamAt(this.job.id, t, { header: false, signal });
    const frames = decodeFramesAt(player.base, new Uint8Array(await response.arrayBuffer()));
    if (frames.length !== 1) throw new DeltaError('corrupt', `the instant ${t} came as ${frames.length} frames, not one`);
    return { header: player.header, frame: frames[0] };
  }

  newPlayer() {
    if (this.player) this.player.dispose();
    this.player = new StreamPlayer(this.playerOptions);
    this.emit('onPlayer', this.player);
    return this.player;
  }

  async followStream() {
    const signal = this.abort.signal;
    for (let attempt = 0; attempt <= MAX_RECONNECTS && !signal.aborted; attempt++) {
      const player = this.newPlayer();
      let error = null;
      try {
        const response = await this.api.jobStream(this.job.id, signal);
        for await (const event of decodeStream(response.body)) {
          if (signal.aborted) return;
          player.handle(event);
          this.emit('onStreamEvent', event.type, player);
        }
        return; // complete
      } catch (e) {
        if (signal.aborted) return;
        error = e;
      }
      // What the cut means depends on the job.
      let job = this.job;
      try {
        job = await this.api.getJob(this.job.id, signal);
        this.setJob(job);
      } catch {
        // Keep the last known document.
      }
      if (job.status === 'failed' || job.status === 'cancelled') {
        // The events side reports the job's error; a 404 or a cut here is its echo.
        if (!(error instanceof ApiError) && error && error.code !== 'truncated') {
          this.emit('onError', error, 'reading the stream');
        }
        return;
      }
      const retryable = error && (error.code === 'truncated' || error.code === 'network_error' || error.name === 'TypeError');
      if (!retryable) {
        this.emit('onError', error, 'reading the stream');
        return;
      }
      await sleep(job.status === 'succeeded' ? 0 : Math.min(300 * 2 ** attempt, 5000), signal);
    }
  }
}
