/**
 * @file Incremental parser of Server-Sent Events (the `text/event-stream`
 * format of the WHATWG HTML standard, §9.2.6).
 *
 * Why not `EventSource`: it cannot send an `Authorization` header, and the
 * API may require `Bearer` keys. So the viewer reads `/v1/jobs/{id}/events`
 * with `fetch` streaming and parses the events here. The parser is pure
 * (text in, events out) so node tests can feed it arbitrary chunkings.
 */

/**
 * One dispatched event.
 * @typedef {object} SseEvent
 * @property {string} event  The event type (`message` when the stream named none).
 * @property {string} data   The data lines joined with `\n`.
 * @property {string} id     The last event id seen (possibly from an earlier event).
 */

/**
 * Parses a `text/event-stream` body fed as decoded text in chunks of any
 * size: a chunk may end inside a line, or between a `\r` and its `\n`.
 */
export class SseParser {
  constructor() {
    /** Text after the last complete line. */
    this.pending = '';
    /** The previous chunk ended with `\r`: a leading `\n` of the next chunk belongs to it. */
    this.sawCr = false;
    this.eventType = '';
    /** @type {string[]} */
    this.dataLines = [];
    this.lastId = '';
    /** Reconnection delay the server asked for (ms), or null. */
    this.retry = null;
  }

  /**
   * Feeds text; returns the events completed by it.
   * @param {string} text
   * @returns {SseEvent[]}
   */
  push(text) {
    if (this.sawCr && text.startsWith('\n')) text = text.slice(1);
    this.sawCr = false;
    const out = [];
    let buffer = this.pending + text;
    let start = 0;
    for (let i = 0; i < buffer.length; i++) {
      const c = buffer[i];
      if (c !== '\n' && c !== '\r') continue;
      this.line(buffer.slice(start, i), out);
      if (c === '\r') {
        if (i + 1 < buffer.length) {
          if (buffer[i + 1] === '\n') i++;
        } else {
          this.sawCr = true;
        }
      }
      start = i + 1;
    }
    this.pending = buffer.slice(start);
    return out;
  }

  /**
   * The stream ended. Per the standard an event without its terminating
   * blank line is discarded, so this returns nothing; it only resets.
   */
  end() {
    this.pending = '';
    this.sawCr = false;
    this.eventType = '';
    this.dataLines = [];
  }

  /** @param {string} line @param {SseEvent[]} out */
  line(line, out) {
    if (line === '') {
      if (this.dataLines.length > 0) {
        out.push({ event: this.eventType || 'message', data: this.dataLines.join('\n'), id: this.lastId });
      }
      this.eventType = '';
      this.dataLines = [];
      return;
    }
    if (line.startsWith(':')) return; // a comment (keep-alive)
    const colon = line.indexOf(':');
    const field = colon < 0 ? line : line.slice(0, colon);
    let value = colon < 0 ? '' : line.slice(colon + 1);
    if (value.startsWith(' ')) value = value.slice(1);
    switch (field) {
      case 'event':
        this.eventType = value;
        break;
      case 'data':
        this.dataLines.push(value);
        break;
      case 'id':
        if (!value.includes('\0')) this.lastId = value;
        break;
      case 'retry':
        if (/^\d+$/.test(value)) this.retry = Number(value);
        break;
      default:
        break; // unknown fields are ignored
    }
  }
}
