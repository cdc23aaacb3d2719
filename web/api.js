/**
 * @file The viewer's client of the treemorph HTTP API (v1).
 *
 * Every call goes through {@link Api#request}, which
 * - adds `Authorization: Bearer KEY` when the user has pasted a key (the
 *   key is read at call time, so changing it takes effect at once),
 * - turns every failure into an {@link ApiError} carrying the API's stable
 *   `code` and its `message` (`{"error": {"code", "message"}}`), so the UI
 *   can always show *code + message* and never swallows an error. Failures
 *   that are not API errors get synthetic codes: `network_error` (no
 *   response at all), `http_<status>` (a response that is not the API's
 *   error body, e.g. from a proxy).
 *
 * The module has no DOM dependency (only `fetch`, `TextDecoder` and
 * streams), so node tests drive it with a fake `fetch`.
 */

import { SseParser } from './sse.js';

/** Where the pasted API key is kept between visits. */
export const KEY_STORAGE = 'treemorph.apiKey';

/** Media types accepted by `POST /v1/trees`. */
export const TREE_MEDIA_TYPES = Object.freeze({
  glb: 'model/gltf-binary',
  gltf: 'model/gltf+json',
  json: 'application/vnd.treemorph.tree+json',
});

/** An error from the API (or from reaching it). */
export class ApiError extends Error {
  /**
   * @param {number} status HTTP status (0 when no response arrived).
   * @param {string} code The API's stable snake_case code.
   * @param {string} message What went wrong, for people.
   */
  constructor(status, code, message) {
    super(message);
    this.name = 'ApiError';
    this.status = status;
    this.code = code;
  }

  /** `code: message`, the form the UI shows. */
  toString() {
    return `${this.code}: ${this.message}`;
  }
}

/**
 * Reads an error response into an ApiError. The API's body is
 * `{"error": {"code", "message"}}`; anything else keeps the status and a
 * snippet of the body so the user still sees what came back.
 * @param {Response} response
 * @returns {Promise<ApiError>}
 */
export async function errorFromResponse(response) {
  let text = '';
  try {
    text = await response.text();
  } catch {
    // The body could not be read; the status alone must do.
  }
  try {
    const body = JSON.parse(text);
    if (body && body.error && typeof body.error.code === 'string') {
      return new ApiError(response.status, body.error.code, String(body.error.message ?? ''));
    }
  } catch {
    // Not JSON: fall through.
  }
  const snippet = text.trim().slice(0, 200);
  const status = `HTTP ${response.status}${response.statusText ? ` ${response.statusText}` : ''}`;
  return new ApiError(response.status, `http_${response.status}`, snippet ? `${status}: ${snippet}` : status);
}

/**
 * The media type to upload `file` with: by extension, else by the GLB
 * magic (`glTF`) or a leading `{` (JSON: glTF if it has an `asset`
 * member, otherwise our tree format). Returns null when it is neither.
 * @param {string} name File name.
 * @param {Uint8Array} head The first bytes of the file (at least 4; the
 *   whole file for JSON sniffing to look for `"asset"`).
 * @returns {string|null}
 */
export function treeMediaType(name, head) {
  const ext = name.toLowerCase().split('.').pop();
  if (ext === 'glb') return TREE_MEDIA_TYPES.glb;
  if (ext === 'gltf') return TREE_MEDIA_TYPES.gltf;
  if (ext === 'json') return TREE_MEDIA_TYPES.json;
  if (head.length >= 4 && head[0] === 0x67 && head[1] === 0x6c && head[2] === 0x54 && head[3] === 0x46) {
    return TREE_MEDIA_TYPES.glb;
  }
  let i = 0;
  while (i < head.length && (head[i] === 0x20 || head[i] === 0x0a || head[i] === 0x0d || head[i] === 0x09)) i++;
  if (head[i] === 0x7b) {
    const text = new TextDecoder().decode(head.subarray(0, 4096));
    return /"asset"\s*:/.test(text) ? TREE_MEDIA_TYPES.gltf : TREE_MEDIA_TYPES.json;
  }
  return null;
}

/** The job statuses after which nothing changes. */
export const TERMINAL_STATUSES = Object.freeze(['succeeded', 'failed', 'cancelled']);

/**
 * The API client.
 */
export class Api {
  /**
   * @param {object} [options]
   * @param {string} [options.baseUrl] Prefix of every path ('' = same origin).
   * @param {typeof fetch} [options.fetch] The fetch to use (tests pass a fake).
   * @param {() => (string|null)} [options.getKey] Returns the API key, or null.
   */
  constructor({ baseUrl = '', fetch: fetchImpl = (...a) => globalThis.fetch(...a), getKey = () => null } = {}) {
    this.baseUrl = baseUrl.replace(/\/$/, '');
    this.fetch = fetchImpl;
    this.getKey = getKey;
  }

  /** Absolute URL of an API path. */
  url(path) {
    return `${this.baseUrl}${path}`;
  }

  /** Headers every request carries (the key, when there is one). */
  authHeaders() {
    const key = (this.getKey() || '').trim();
    return key ? { Authorization: `Bearer ${key}` } : {};
  }

  /**
   * Sends a request; resolves to the Response when its status is 2xx (or
   * 304), throws an ApiError otherwise.
   * @param {string} method
   * @param {string} path
   * @param {object} [options]
   * @param {unknown} [options.json] A body sent as `application/json`.
   * @param {BodyInit} [options.body] A raw body (with `contentType`).
   * @param {string} [options.contentType]
   * @param {Record<string, string|number|undefined|null>} [options.query]
   * @param {AbortSignal} [options.signal]
   * @param {Record<string, string>} [options.headers]
   * @returns {Promise<Response>}
   */
  async request(method, path, { json, body, contentType, query, signal, headers = {} } = {}) {
    let url = this.url(path);
    if (query) {
      const params = new URLSearchParams();
      for (const [k, v] of Object.entries(query)) if (v !== undefined && v !== null && v !== '') params.set(k, String(v));
      const qs = params.toString();
      if (qs) url += `?${qs}`;
    }
    const h = { ...this.authHeaders(), ...headers };
    if (json !== undefined) {
      h['Content-Type'] = 'application/json';
      body = JSON.stringify(json);
    } else if (contentType) {
      h['Content-Type'] = contentType;
    }
    let response;
    try {
      response = await this.fetch(url, { method, headers: h, body, signal });
    } catch (e) {
      if (e && e.name === 'AbortError') throw e;
      throw new ApiError(0, 'network_error', `could not reach the server (${method} ${path}): ${e && e.message ? e.message : e}`);
    }
    if (!response.ok && response.status !== 304) throw await errorFromResponse(response);
    return response;
  }

  /** A request whose 2xx response is JSON (or empty: returns null). */
  async json(method, path, options) {
    const response = await this.request(method, path, options);
    const text = await response.text();
    if (!text) return null;
    try {
      return JSON.parse(text);
    } catch {
      throw new ApiError(response.status, 'invalid_response', `${method} ${path} answered ${response.status} with a body that is not JSON`);
    }
  }

  // ---- trees ----

  /** `GET /v1/trees`: one page, newest first. */
  listTrees({ limit = 50, cursor } = {}) {
    return this.json('GET', '/v1/trees', { query: { limit, cursor } });
  }

  /**
   * `POST /v1/trees`: uploads a file (GLB, glTF JSON or our tree JSON).
   * @param {Blob & {name?: string}} file
   * @param {string} [name] Name for people; the file name without extension by default.
   */
  async uploadTree(file, name) {
    const head = new Uint8Array(await file.slice(0, 4096).arrayBuffer());
    const type = treeMediaType(file.name || '', head);
    if (!type) {
      throw new ApiError(0, 'unsupported_file', `${file.name || 'this file'} is not a .glb, .gltf or tree .json file`);
    }
    const fallback = (file.name || 'tree').replace(/\.[^.]*$/, '') || 'tree';
    return this.json('POST', '/v1/trees', { body: file, contentType: type, query: { name: name || fallback } });
  }

  /** `POST /v1/trees/generate`. */
  generateTree({ preset, seed, size }) {
    const json = { preset, seed };
    if (size !== undefined && size !== null && size !== '') json.size = size;
    return this.json('POST', '/v1/trees/generate', { json });
  }

  /** `DELETE /v1/trees/{id}`. */
  deleteTree(id) {
    return this.json('DELETE', `/v1/trees/${encodeURIComponent(id)}`);
  }

  /** `GET /v1/trees/{id}/model.glb` as bytes. */
  async treeGlb(id, signal) {
    const response = await this.request('GET', `/v1/trees/${encodeURIComponent(id)}/model.glb`, { signal });
    return response.arrayBuffer();
  }

  // ---- jobs ----

  /** `POST /v1/jobs`: starts a morph or sketch job; resolves to the job document. */
  createJob(request) {
    return this.json('POST', '/v1/jobs', { json: request });
  }

  /** `GET /v1/jobs/{id}`. */
  getJob(id, signal) {
    return this.json('GET', `/v1/jobs/${encodeURIComponent(id)}`, { signal });
  }

  /** `POST /v1/jobs/{id}/cancel`: asks the job to stop (never deletes it). */
  cancelJob(id) {
    return this.json('POST', `/v1/jobs/${encodeURIComponent(id)}/cancel`);
  }

  /** Paths of a job's downloadable outputs. */
  jobPaths(id) {
    const base = `/v1/jobs/${encodeURIComponent(id)}`;
    return {
      animation: `${base}/animation.glb`,
      stream: `${base}/stream`,
      metrics: `${base}/metrics.json`,
      frame: (n) => `${base}/frames/${n}.glb`,
      frameAt: `${base}/frame.glb`,
    };
  }

  /** `GET /v1/jobs/{id}/stream`: the Response whose body is the delta stream. */
  jobStream(id, signal) {
    return this.request('GET', `/v1/jobs/${encodeURIComponent(id)}/stream`, { signal });
  }

  /**
   * `GET /v1/jobs/{id}/stream?t=`: the Response whose body is a one-frame
   * delta stream of the instant `t` in [0, 1] based on the job's first
   * frame (a succeeded job only; rendered on request); with `header:
   * false`, only its frame record, which decodes after the job's own
   * stream header (`decodeFramesAt`).
   */
  jobStreamAt(id, t, { header = true, signal } = {}) {
    const query = header ? { t } : { t, header: 'false' };
    return this.request('GET', `/v1/jobs/${encodeURIComponent(id)}/stream`, { query, signal });
  }

  /**
   * `GET /v1/jobs/{id}/events`, parsed: yields `{event, data}` with `data`
   * parsed as JSON (the raw string when it is not JSON) until the server
   * ends the stream or `signal` aborts. The caller reconnects if it ends
   * before a terminal event (the server starts every connection with a
   * `job` event holding the present state, so nothing is lost).
   * @param {string} id
   * @param {AbortSignal} [signal]
   */
  async *jobEvents(id, signal) {
    const response = await this.request('GET', `/v1/jobs/${encodeURIComponent(id)}/events`, {
      signal,
      headers: { Accept: 'text/event-stream' },
    });
    const parser = new SseParser();
    const decoder = new TextDecoder();
    const reader = response.body.getReader();
    try {
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        for (const e of parser.push(decoder.decode(value, { stream: true }))) {
          let data = e.data;
          try {
            data = JSON.parse(e.data);
          } catch {
            // keep the raw text
          }
          yield { event: e.event, data };
        }
      }
    } finally {
      reader.releaseLock();
      try {
        await response.body.cancel();
      } catch {
        // already closed
      }
    }
  }

  /**
   * Fetches an output with the key and returns it as a Blob (downloads
   * cannot use a plain link when the API needs a Bearer key).
   */
  async blob(path) {
    const response = await this.request('GET', path);
    return response.blob();
  }
}
