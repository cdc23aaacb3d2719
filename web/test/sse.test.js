// The Server-Sent Events parser, fed the way a fetch body arrives: in
// chunks that split lines, fields and CRLF pairs anywhere.

import { test } from 'node:test';
import assert from 'node:assert/strict';

import { SseParser } from '../sse.js';

const body =
  ': keep-alive\n\n' +
  'event: job\ndata: {"status":"queued"}\n\n' +
  'event: stage\r\ndata: {"stage":"planning",\r\ndata: "progress":0.1}\r\n\r\n' +
  'event:progress\rdata:{"progress":0.5}\r\r' +
  'id: 7\nretry: 1500\ndata\n\n' +
  'event: frame\ndata: {"index":3}\n\n' +
  'event: done\ndata: {"status":"succeeded"}\n';

const expected = [
  { event: 'job', data: '{"status":"queued"}', id: '' },
  { event: 'stage', data: '{"stage":"planning",\n"progress":0.1}', id: '' },
  { event: 'progress', data: '{"progress":0.5}', id: '' },
  { event: 'message', data: '', id: '7' },
  { event: 'frame', data: '{"index":3}', id: '7' },
];

function parseChunks(chunks) {
  const p = new SseParser();
  const out = [];
  for (const c of chunks) out.push(...p.push(c));
  return { out, parser: p };
}

test('a whole body parses into its events; an unterminated last event is held back', () => {
  const { out, parser } = parseChunks([body]);
  assert.deepEqual(out, expected);
  assert.equal(parser.retry, 1500);
  // The final event has no blank line yet: a later newline completes it.
  assert.deepEqual(parser.push('\n'), [{ event: 'done', data: '{"status":"succeeded"}', id: '7' }]);
});

test('every split into two chunks, and one character at a time, give the same events', () => {
  for (let i = 0; i <= body.length; i++) {
    assert.deepEqual(parseChunks([body.slice(0, i), body.slice(i)]).out, expected, `split at ${i}`);
  }
  assert.deepEqual(parseChunks([...body]).out, expected);
});

test('end() discards a partial event', () => {
  const p = new SseParser();
  p.push('event: done\ndata: x');
  p.end();
  assert.deepEqual(p.push('\n\n'), []);
});
