// JobRun against a fake API: progress events reach the callbacks, the
// stream feeds a player, a stream cut short while the job still runs starts
// over with a new player (a retry replaced the attempt), a job that failed
// keeps the frames already shown, and a dropped event connection
// reconnects.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';

import { ApiError } from '../api.js';
import { JobRun } from '../jobs.js';

const small = new Uint8Array(readFileSync(new URL('../../api/tests/fixtures/small.tmd', import.meta.url)));

/** A body that delivers `bytes` in a few chunks. */
function body(bytes) {
  return new ReadableStream({
    start(c) {
      for (let i = 0; i < bytes.length; i += 100) c.enqueue(bytes.slice(i, i + 100));
      c.close();
    },
  });
}

const doc = (status, extra = {}) => ({ id: 'j1', kind: 'morph', status, progress: status === 'succeeded' ? 1 : 0.5, frames: 5, frames_ready: 0, attempt: 1, ...extra });

/** A fake Api; `events` is a list of SSE connections (arrays of events, or an Error to throw). */
function fakeApi({ events, streams, jobs }) {
  const calls = { events: 0, streams: 0, getJob: 0, cancel: 0 };
  return {
    calls,
    async createJob(request) {
      return { ...doc('queued'), kind: request.kind };
    },
    async *jobEvents() {
      const connection = events[Math.min(calls.events++, events.length - 1)];
      if (connection instanceof Error) throw connection;
      for (const e of connection) yield e;
    },
    async jobStream() {
      const s = streams[Math.min(calls.streams++, streams.length - 1)];
      if (s instanceof Error) throw s;
      return { body: body(s) };
    },
    async getJob() {
      return jobs[Math.min(calls.getJob++, jobs.length - 1)];
    },
    async cancelJob() {
      calls.cancel++;
      return doc('cancelled');
    },
  };
}

function record() {
  const log = { docs: [], jobs: [], stages: [], frames: [], players: [], events: [], errors: [], ends: [] };
  return {
    log,
    callbacks: {
      onJob: (j) => {
        log.jobs.push(j.status);
        log.docs.push(j);
      },
      onStage: (s, p) => log.stages.push([s, p]),
      onProgress: (p) => log.stages.push(['progress', p]),
      onFrameReady: (i) => log.frames.push(i),
      onPlayer: (p) => log.players.push(p),
      onStreamEvent: (type) => log.events.push(type),
      onError: (e, context) => log.errors.push(`${context}: ${e.code || e.message}`),
      onEnd: (j) => log.ends.push(j.status),
    },
  };
}

const quick = { playerOptions: { loadTexture: null } };

test('a job that succeeds: events reach the callbacks and the whole stream plays', async () => {
  const api = fakeApi({
    events: [[
      { event: 'job', data: doc('running') },
      { event: 'stage', data: { stage: 'frames', progress: 0.3 } },
      { event: 'progress', data: { progress: 0.6 } },
      { event: 'frame', data: { index: 0 } },
      { event: 'done', data: doc('succeeded') },
    ]],
    streams: [small],
    jobs: [doc('succeeded')],
  });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'morph', source: 'a', target: 'b', frames: 5 });
  await run.done;
  assert.deepEqual(log.jobs, ['queued', 'running', 'running', 'running', 'running', 'succeeded']);
  assert.deepEqual(log.stages, [['frames', 0.3], ['progress', 0.6]]);
  // Incremental events update the document: a queued job that progresses is running.
  const before = log.docs[4];
  assert.deepEqual([before.status, before.stage, before.progress, before.frames_ready], ['running', 'frames', 0.6, 1]);
  assert.deepEqual(log.frames, [0]);
  assert.deepEqual(log.ends, ['succeeded']);
  assert.equal(log.players.length, 1);
  assert.deepEqual(log.events, ['header', 'frame', 'frame', 'frame', 'frame', 'frame', 'end']);
  assert.equal(run.player.received, 5);
  assert.ok(run.player.complete);
  assert.deepEqual(log.errors, []);
});

test('a stream cut while the job runs starts over with a new player', async () => {
  const cut = small.slice(0, 400);
  const api = fakeApi({
    events: [[{ event: 'job', data: doc('running') }, { event: 'done', data: doc('succeeded') }]],
    streams: [cut, small],
    jobs: [doc('running', { attempt: 2 }), doc('succeeded')],
  });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'morph' });
  await run.done;
  assert.equal(api.calls.streams, 2);
  assert.equal(log.players.length, 2, 'a fresh player for the new attempt');
  assert.ok(run.player.complete);
  assert.equal(run.player.received, 5);
  assert.deepEqual(log.errors, []);
});

test('a job that fails keeps the frames already received and reports no stream error', async () => {
  const cut = small.slice(0, 500);
  const failed = doc('failed', { error: { code: 'internal', message: 'boom' } });
  const api = fakeApi({
    events: [[{ event: 'failed', data: failed }]],
    streams: [cut],
    jobs: [failed],
  });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'sketch' });
  await run.done;
  assert.equal(api.calls.streams, 1);
  assert.equal(log.players.length, 1);
  assert.ok(run.player.received > 0 && !run.player.complete);
  assert.deepEqual(log.ends, ['failed']);
  assert.deepEqual(log.errors, []);
});

test('a damaged stream is reported, not retried', async () => {
  const bad = small.slice();
  bad[300] ^= 0xff;
  const api = fakeApi({ events: [[{ event: 'done', data: doc('succeeded') }]], streams: [bad], jobs: [doc('succeeded')] });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'morph' });
  await run.done;
  assert.equal(api.calls.streams, 1);
  assert.deepEqual(log.errors, ['reading the stream: checksum_mismatch']);
});

test('a dropped event connection reconnects; a 404 stops following', async () => {
  const api = fakeApi({
    events: [[{ event: 'job', data: doc('running') }], [{ event: 'done', data: doc('succeeded') }]],
    streams: [small],
    jobs: [doc('running'), doc('succeeded')],
  });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'morph' });
  await run.done;
  assert.equal(api.calls.events, 2);
  assert.deepEqual(log.ends, ['succeeded']);

  const gone = fakeApi({ events: [new ApiError(404, 'not_found', 'no such job')], streams: [small], jobs: [doc('succeeded')] });
  const r2 = record();
  const run2 = new JobRun(gone, r2.callbacks, quick);
  await run2.start({ kind: 'morph' });
  await run2.done;
  assert.equal(gone.calls.events, 1);
  assert.deepEqual(r2.log.errors, ['following the job: not_found']);
});

test('cancel asks the server and reports the cancelled job', async () => {
  const api = fakeApi({ events: [[{ event: 'job', data: doc('running') }]], streams: [small], jobs: [doc('cancelled')] });
  const { log, callbacks } = record();
  const run = new JobRun(api, callbacks, quick);
  await run.start({ kind: 'morph' });
  await run.cancel();
  await run.done;
  assert.equal(api.calls.cancel, 1);
  assert.ok(log.ends.includes('cancelled'));
});
