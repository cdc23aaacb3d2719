// The instant scrubber (scrub.js): quantised instants, latest wins with one
// request in flight, every answer delivered, a small LRU cache, errors
// reported without stopping later requests.

import { test } from 'node:test';
import assert from 'node:assert/strict';

import { INSTANT_STEPS, InstantScrubber, quantise } from '../scrub.js';

/** A fetch whose answers the test releases by hand. */
function manualFetch() {
  const pending = [];
  const fetch = (t) =>
    new Promise((resolve, reject) => {
      pending.push({ t, resolve: () => resolve({ t }), reject });
    });
  return { fetch, pending };
}

const tick = () => new Promise((r) => setImmediate(r));

test('instants are clamped and rounded to multiples of 1/4096', () => {
  assert.equal(quantise(0.375), 0.375);
  assert.equal(quantise(1 / 3), Math.round(INSTANT_STEPS / 3) / INSTANT_STEPS);
  assert.equal(quantise(-1), 0);
  assert.equal(quantise(7), 1);
  assert.equal(quantise(Number.NaN), 0);
});

test('one request in flight; moves meanwhile only replace the next instant; every answer is delivered', async () => {
  const { fetch, pending } = manualFetch();
  const shown = [];
  const s = new InstantScrubber(fetch, { onFrame: (t) => shown.push(t) });
  s.want(0.25);
  s.want(0.5);
  s.want(0.75);
  await tick();
  assert.deepEqual(pending.map((p) => p.t), [0.25], 'more than one request in flight');
  pending[0].resolve();
  await tick();
  assert.deepEqual(pending.map((p) => p.t), [0.25, 0.75], 'the drag’s last instant is not the one fetched next');
  pending[1].resolve();
  await s.idle;
  assert.deepEqual(shown, [0.25, 0.75]);
  assert.equal(s.fetches, 2);
});

test('a cached instant is shown at once without a request; the cache drops the least recently used', async () => {
  let fetches = 0;
  const shown = [];
  const s = new InstantScrubber(
    async (t) => {
      fetches += 1;
      return { t };
    },
    { onFrame: (t) => shown.push(t) },
    { cacheSize: 2 },
  );
  for (const t of [0.1, 0.2]) {
    s.want(t);
    await s.idle;
  }
  s.want(0.1); // hit: refreshes 0.1
  assert.equal(fetches, 2);
  s.want(0.3); // evicts 0.2
  await s.idle;
  s.want(0.1);
  assert.equal(fetches, 3);
  s.want(0.2);
  await s.idle;
  assert.equal(fetches, 4, '0.2 should have been evicted');
  assert.deepEqual(shown, [0.1, 0.2, 0.1, 0.3, 0.1, 0.2].map(quantise));
});

test('a failed fetch is reported and later instants are still fetched; cancel drops the next instant', async () => {
  const errors = [];
  const shown = [];
  const s = new InstantScrubber(
    async (t) => {
      if (t === 0.5) throw new Error('409 not_ready');
      return { t };
    },
    { onFrame: (t) => shown.push(t), onError: (e, t) => errors.push([e.message, t]) },
  );
  s.want(0.5);
  await s.idle;
  s.want(0.25);
  await s.idle;
  assert.deepEqual(errors, [['409 not_ready', 0.5]]);
  assert.deepEqual(shown, [0.25]);
  const { fetch, pending } = manualFetch();
  const t = new InstantScrubber(fetch, { onFrame: (x) => shown.push(x) });
  t.want(0.125);
  t.want(0.625);
  t.cancel();
  pending[0].resolve();
  await t.idle;
  assert.equal(pending.length, 1, 'a cancelled instant was fetched');
});
