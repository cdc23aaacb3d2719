// The API client against a fake fetch: the Bearer key, the uniform error
// body turned into code + message, non-API errors, media-type sniffing for
// uploads and the SSE reader.

import { test } from 'node:test';
import assert from 'node:assert/strict';

import { Api, ApiError, TREE_MEDIA_TYPES, treeMediaType } from '../api.js';

/** A fake fetch that records requests and answers from `respond`. */
function fakeFetch(respond) {
  const calls = [];
  const fetch = async (url, init) => {
    calls.push({ url, ...init });
    return respond(url, init);
  };
  return { fetch, calls };
}

const json = (status, body) =>
  new Response(JSON.stringify(body), { status, headers: { 'Content-Type': 'application/json' } });

test('the key is sent as a Bearer token, read at call time', async () => {
  let key = null;
  const { fetch, calls } = fakeFetch(() => json(200, { items: [] }));
  const api = new Api({ fetch, getKey: () => key });
  await api.listTrees({ limit: 5 });
  assert.equal(calls[0].headers.Authorization, undefined);
  assert.equal(calls[0].url, '/v1/trees?limit=5');
  key = '  sk_test  ';
  await api.listTrees({ cursor: 'abc' });
  assert.equal(calls[1].headers.Authorization, 'Bearer sk_test');
  assert.equal(calls[1].url, '/v1/trees?limit=50&cursor=abc');
});

test('API errors carry the code and message of the uniform body', async () => {
  const { fetch } = fakeFetch(() =>
    json(422, { error: { code: 'invalid_request', message: 'size 40 is out of range' } }),
  );
  const api = new Api({ fetch });
  await assert.rejects(api.generateTree({ preset: 'maple', seed: 1, size: 40 }), (e) => {
    assert.ok(e instanceof ApiError);
    assert.equal(e.status, 422);
    assert.equal(e.code, 'invalid_request');
    assert.equal(String(e), 'invalid_request: size 40 is out of range');
    return true;
  });
});

test('errors that are not API errors keep their status and a snippet', async () => {
  const api = new Api({ fetch: async () => new Response('<html>Bad Gateway</html>', { status: 502, statusText: 'Bad Gateway' }) });
  await assert.rejects(api.getJob('x'), { code: 'http_502', message: 'HTTP 502 Bad Gateway: <html>Bad Gateway</html>' });
  const down = new Api({ fetch: async () => { throw new TypeError('fetch failed'); } });
  await assert.rejects(down.getJob('x'), { code: 'network_error', status: 0 });
});

test('request bodies: generate sends JSON without an empty size; jobs are POSTed as given', async () => {
  const { fetch, calls } = fakeFetch(() => json(201, { id: 't' }));
  const api = new Api({ fetch, baseUrl: 'http://h:1/' });
  await api.generateTree({ preset: 'shrub', seed: 3, size: '' });
  assert.equal(calls[0].url, 'http://h:1/v1/trees/generate');
  assert.deepEqual(JSON.parse(calls[0].body), { preset: 'shrub', seed: 3 });
  assert.equal(calls[0].headers['Content-Type'], 'application/json');
  const job = { kind: 'morph', source: 'a', target: 'b', frames: 12 };
  await api.createJob(job);
  assert.deepEqual(JSON.parse(calls[1].body), job);
  assert.equal(api.jobPaths('j 1').frame(3), '/v1/jobs/j%201/frames/3.glb');
});

test('uploads pick the media type by extension or by sniffing', async () => {
  const enc = (s) => new TextEncoder().encode(s);
  assert.equal(treeMediaType('a.GLB', new Uint8Array()), TREE_MEDIA_TYPES.glb);
  assert.equal(treeMediaType('tree', enc('glTF\x02\0\0\0')), TREE_MEDIA_TYPES.glb);
  assert.equal(treeMediaType('tree', enc(' {"asset": {"version": "2.0"}}')), TREE_MEDIA_TYPES.gltf);
  assert.equal(treeMediaType('tree', enc('{"nodes": []}')), TREE_MEDIA_TYPES.json);
  assert.equal(treeMediaType('photo.png', enc('\x89PNG')), null);

  const { fetch, calls } = fakeFetch(() => json(201, { id: 't' }));
  const api = new Api({ fetch });
  const file = new File([enc('glTF\x02\0\0\0rest')], 'my oak.glb');
  await api.uploadTree(file);
  assert.equal(calls[0].url, '/v1/trees?name=my+oak');
  assert.equal(calls[0].headers['Content-Type'], 'model/gltf-binary');
  await assert.rejects(api.uploadTree(new File([enc('\x89PNG')], 'x.png')), { code: 'unsupported_file' });
  assert.equal(calls.length, 1, 'nothing sent for an unsupported file');
});

test('job events are parsed from the streamed body, JSON data decoded', async () => {
  const chunks = ['event: job\ndata: {"status":"run', 'ning"}\n\n: ping\n\nevent: frame\ndata: {"index":0}\n\n'];
  const body = new ReadableStream({
    start(c) {
      for (const s of chunks) c.enqueue(new TextEncoder().encode(s));
      c.close();
    },
  });
  const { fetch, calls } = fakeFetch(() => new Response(body, { status: 200 }));
  const api = new Api({ fetch, getKey: () => 'k' });
  const events = [];
  for await (const e of api.jobEvents('j1')) events.push(e);
  assert.deepEqual(events, [
    { event: 'job', data: { status: 'running' } },
    { event: 'frame', data: { index: 0 } },
  ]);
  assert.equal(calls[0].headers.Accept, 'text/event-stream');
  assert.equal(calls[0].headers.Authorization, 'Bearer k');
});
