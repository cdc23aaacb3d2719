/**
 * @file The page: wires the API client, the 3D view, the sketch pad, the
 * trees panel, the job panel and the playback bar together.
 *
 * State kept here, and why:
 * - `viewed`: the tree on screen (its GLB) — the one a sketch is drawn over
 *   and sent with.
 * - `run`: the job being followed. Starting another job stops *following*
 *   the previous one (it keeps running on the server) so only one stream
 *   plays at a time.
 * - What the view shows is either the viewed tree or the run's player;
 *   "Show the animation" switches back to the player.
 *
 * Every error reaches {@link report}, which lists it as `code: message`
 * with what was being done; nothing is swallowed.
 */

import { Api, ApiError, KEY_STORAGE } from './api.js';
import { JobRun } from './jobs.js';
import { SketchPad } from './sketchpad.js';
import { Timeline } from './timeline.js';
import { TreesPanel, h } from './trees.js';
import { Viewer, disposeObject } from './viewer.js';

const $ = (id) => {
  const el = document.getElementById(id);
  if (!el) throw new Error(`the page has no #${id}`);
  return el;
};

/** The stages a job goes through, in order (api/src/jobs.rs `JobInfo::stage`). */
const STAGES = ['loading', 'analysing', 'planning', 'frames', 'finishing'];

// ---- errors and status ----

/**
 * Shows an error as `code: message (context)`.
 * @param {Error} error
 * @param {string} [context] What was being done.
 */
function report(error, context = '') {
  console.error(context, error);
  const code = error && error.code ? error.code : 'error';
  const message = error && error.message ? error.message : String(error);
  const item = h(
    'li',
    { class: 'error' },
    h('strong', { class: 'code' }, code),
    ': ',
    h('span', { class: 'message' }, message),
    context ? h('small', {}, ` — ${context}`) : null,
    h('button', { type: 'button', class: 'icon', 'aria-label': 'Dismiss this error', onclick: () => item.remove() }, '×'),
  );
  const list = $('errors');
  list.append(item);
  while (list.children.length > 6) list.firstElementChild.remove();
}

function status(message) {
  $('status').textContent = message;
}

window.addEventListener('unhandledrejection', (e) => report(e.reason, 'unexpected'));
window.addEventListener('error', (e) => report(e.error || new Error(e.message), 'unexpected'));

// ---- the API key ----

function storedKey() {
  try {
    return localStorage.getItem(KEY_STORAGE);
  } catch {
    return null; // storage disabled: no key
  }
}

const api = new Api({ getKey: storedKey });
{
  const input = $('api-key');
  input.value = storedKey() || '';
  $('key-form').addEventListener('submit', (e) => {
    e.preventDefault();
    localStorage.setItem(KEY_STORAGE, input.value.trim());
    status(input.value.trim() ? 'API key saved.' : 'No API key.');
    trees.load();
  });
  $('key-clear').addEventListener('click', () => {
    localStorage.removeItem(KEY_STORAGE);
    input.value = '';
    status('API key forgotten.');
    trees.load();
  });
}

// ---- view, sketch pad, timeline ----

const viewer = new Viewer($('view'));
const timeline = new Timeline(
  { play: $('play'), scrub: $('scrub'), label: $('frame-label'), fps: $('fps'), loop: $('loop'), bar: $('timeline') },
  viewer,
);
const pad = new SketchPad($('sketch-overlay'), {
  currentView: () => viewer.currentView(),
  isAt: (view) => viewer.isAt(view),
  onChange: () => updateSketchUi(),
});
viewer.onViewChange(() => pad.redraw());

/** @type {{tree: object|null, object: import('three').Object3D|null, loading: AbortController|null}} */
const viewed = { tree: null, object: null, loading: null };
/** @type {JobRun|null} */
let run = null;
/** What the view shows: 'tree', 'player' or 'none'. */
let showing = 'none';

function caption(text) {
  $('caption').textContent = text;
}

/** "maple-1 → conifer-2" or "maple-1 → sketch": what a job animates. */
function describe(request) {
  const name = (id) => trees.trees.find((t) => t.id === id)?.name || id.slice(0, 8);
  return request.kind === 'morph' ? `${name(request.source)} → ${name(request.target)}` : `${name(request.tree)} → sketch`;
}

/** Fetches and shows a tree's GLB. */
async function viewTree(tree, { frame = true } = {}) {
  viewed.loading?.abort();
  const loading = new AbortController();
  viewed.loading = loading;
  trees.setViewed(tree.id);
  $('sketch-tree').textContent = tree.name;
  caption(`Loading ${tree.name}…`);
  try {
    const bytes = await api.treeGlb(tree.id, loading.signal);
    const object = await viewer.parseGlb(bytes);
    if (loading.signal.aborted) {
      disposeObject(object);
      return;
    }
    if (viewed.object) disposeObject(viewed.object);
    viewed.tree = tree;
    viewed.object = object;
    showTree({ frame });
  } catch (e) {
    if (e.name !== 'AbortError') {
      report(e, `loading ${tree.name}`);
      caption('');
    }
  } finally {
    if (viewed.loading === loading) viewed.loading = null;
  }
}

function showTree({ frame = true } = {}) {
  if (!viewed.object) return;
  if (pad.active && !pad.sketch.empty) frame = false; // keep the sketch's camera
  viewer.setContent(viewed.object, { frame });
  showing = 'tree';
  timeline.attach(null);
  caption(viewed.tree.name);
  $('show-result').hidden = !(run && run.player && run.player.header);
}

function showPlayer(player, { frame = true } = {}) {
  if (!player.header) return;
  if (pad.active) setSketching(false);
  // A sketch result is shown from the camera it was drawn from, so the
  // outline (still on the overlay) can be compared with the animation.
  const sketchView = run && run.request.kind === 'sketch' ? run.request.view : null;
  viewer.setContent(player.group, { box: player.bounds(), frame: frame && !sketchView });
  if (sketchView) viewer.setView(sketchView);
  showing = 'player';
  timeline.attach(player);
  offerInstants();
  $('show-result').hidden = true;
  caption(run ? describe(run.request) : '');
}

/**
 * Lets the timeline fetch instants between frames once the job it plays
 * has succeeded (the server renders none before).
 */
function offerInstants() {
  const current = run;
  if (current && current.player && timeline.player === current.player && current.job?.status === 'succeeded') {
    timeline.setInstantSource((t) => current.instantAt(t));
  }
}

// ---- trees panel ----

const trees = new TreesPanel(
  { list: $('tree-list'), more: $('more-trees'), empty: $('trees-empty'), generate: $('generate-form'), upload: $('upload-form') },
  api,
  {
    onView: (tree) => viewTree(tree),
    onChange: (list) => fillTreeSelects(list),
    report,
    status,
  },
);

/** Keeps the morph selects in step with the list, preserving the choices. */
function fillTreeSelects(list) {
  const source = $('morph-source');
  const target = $('morph-target');
  for (const [select, fallback] of [[source, 1], [target, 0]]) {
    const before = select.value;
    select.replaceChildren(...list.map((t) => h('option', { value: t.id }, `${t.name} (${t.id.slice(-6)})`)));
    if (list.some((t) => t.id === before)) select.value = before;
    else if (list.length) select.value = list[Math.min(fallback, list.length - 1)].id;
  }
  $('morph-run').disabled = list.length === 0;
}

// Drag and drop anywhere on the page uploads.
{
  let depth = 0;
  const hint = $('drop-hint');
  const hasFiles = (e) => [...(e.dataTransfer?.types || [])].includes('Files');
  document.addEventListener('dragenter', (e) => {
    if (!hasFiles(e)) return;
    depth += 1;
    hint.hidden = false;
  });
  document.addEventListener('dragleave', (e) => {
    if (!hasFiles(e)) return;
    depth = Math.max(0, depth - 1);
    if (depth === 0) hint.hidden = true;
  });
  document.addEventListener('dragover', (e) => {
    if (hasFiles(e)) e.preventDefault();
  });
  document.addEventListener('drop', (e) => {
    if (!hasFiles(e)) return;
    e.preventDefault();
    depth = 0;
    hint.hidden = true;
    trees.upload([...e.dataTransfer.files]);
  });
}

// ---- frames inputs: slider and number kept in step ----

function linkFrames(rangeId, numberId) {
  const range = $(rangeId);
  const number = $(numberId);
  range.addEventListener('input', () => {
    number.value = range.value;
  });
  number.addEventListener('input', () => {
    if (number.value !== '') range.value = number.value;
  });
  return () => Number(number.value);
}
const morphFrames = linkFrames('morph-frames-range', 'morph-frames');
const sketchFrames = linkFrames('sketch-frames-range', 'sketch-frames');

// ---- morph ----

$('morph-form').addEventListener('submit', (e) => {
  e.preventDefault();
  const source = $('morph-source').value;
  const target = $('morph-target').value;
  if (!source || !target) {
    report(new Error('choose the two trees to morph between'), 'starting a morph');
    return;
  }
  startJob({ kind: 'morph', source, target, frames: morphFrames() });
});

// ---- sketch ----

function setSketching(on) {
  if (on && !viewed.tree) {
    report(new Error('show a tree first (pick one in the list, or generate one)'), 'sketching');
    return;
  }
  if (on) {
    if (showing !== 'tree') showTree({ frame: false });
    if (pad.sketch.view) viewer.setView(pad.sketch.view);
  }
  viewer.setOrbitEnabled(!on);
  pad.setActive(on);
  // On a narrow window the button is far below the view: bring the pad on screen.
  if (on) $('canvas-wrap').scrollIntoView({ block: 'nearest' });
  const toggle = $('sketch-toggle');
  toggle.setAttribute('aria-pressed', String(on));
  toggle.textContent = on ? 'Done drawing' : 'Draw sketch';
  updateSketchUi();
}

function updateSketchUi() {
  const s = pad.sketch;
  $('sketch-undo').disabled = s.empty;
  $('sketch-clear').disabled = s.empty;
  const info = $('sketch-info');
  if (s.empty) {
    info.textContent = pad.active
      ? 'Drag inside the square frame to draw; each drag (or click) continues the outline. Esc: done; Ctrl+Z: undo.'
      : 'Press “Draw sketch”, then drag over the view. The camera is frozen while you draw.';
  } else {
    const problem = s.problem();
    info.textContent = `${s.points.length} points, ${s.closed ? 'closed' : 'open'}, ${s.strokeStarts.length} stroke(s).` + (problem ? ` To run: ${problem}.` : '');
  }
}

$('sketch-toggle').addEventListener('click', () => setSketching(!pad.active));
$('sketch-undo').addEventListener('click', () => pad.undo());
$('sketch-clear').addEventListener('click', () => pad.clear());
$('sketch-closed').addEventListener('change', (e) => pad.setClosed(e.target.checked));
document.addEventListener('keydown', (e) => {
  if (!pad.active) return;
  if (e.key === 'Escape') setSketching(false);
  else if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === 'z') {
    e.preventDefault();
    pad.undo();
  }
});
$('sketch-form').addEventListener('submit', (e) => {
  e.preventDefault();
  const s = pad.sketch;
  const problem = s.problem();
  if (!viewed.tree) {
    report(new Error('show the tree to sketch over first'), 'starting a sketch job');
    return;
  }
  if (problem) {
    report(new Error(problem), 'starting a sketch job');
    return;
  }
  const request = { kind: 'sketch', tree: viewed.tree.id, view: s.view, sketch: s.toRequest(), frames: sketchFrames() };
  if ($('sketch-fit-crown').checked) request.options = { fit: 'crown' };
  setSketching(false);
  startJob(request);
});
updateSketchUi();

// ---- jobs ----

function renderStages(current, jobStatus) {
  const list = $('job-stages');
  const at = STAGES.indexOf(current);
  list.replaceChildren(
    ...STAGES.map((name, i) => {
      let state = i < at ? 'done' : i === at ? 'current' : 'todo';
      if (jobStatus === 'succeeded') state = 'done';
      return h('li', { class: state, 'aria-current': state === 'current' ? 'step' : null }, name);
    }),
  );
}

function renderJob(job) {
  $('jobbar').hidden = false;
  const pct = Math.round((job.progress || 0) * 100);
  const parts = [`${job.kind} job ${job.id.slice(0, 8)}… ${job.status}`];
  if (job.stage && !['succeeded', 'cancelled', 'failed'].includes(job.status)) parts.push(`stage ${job.stage}`);
  parts.push(`${pct}%`);
  if (job.frames) parts.push(`${job.frames_ready ?? 0}/${job.frames} frames ready`);
  if (job.attempt > 1) parts.push(`attempt ${job.attempt}`);
  $('job-status').textContent = parts.join(' · ');
  const bar = $('job-progress');
  bar.value = job.status === 'succeeded' ? 1 : job.progress || 0;
  bar.setAttribute('aria-valuetext', `${pct}%${job.stage ? `, ${job.stage}` : ''}`);
  renderStages(job.stage, job.status);
  $('job-cancel').disabled = ['succeeded', 'failed', 'cancelled'].includes(job.status);
  renderDownloads(job);
}

/** Download links; with a key, clicks fetch with the header (a plain link cannot send it). */
function renderDownloads(job) {
  const paths = api.jobPaths(job.id);
  const links = job.result?.links || {};
  const items = [];
  const link = (label, path, filename) =>
    h('li', {}, h('a', { href: api.url(path), download: filename, onclick: (e) => download(e, path, filename) }, label));
  if (job.status === 'succeeded') {
    if (links.animation !== undefined || !job.result) items.push(link('Animation (.glb)', links.animation || paths.animation, `treemorph-${job.id}.glb`));
    if (links.stream !== undefined || !job.result) items.push(link('Delta stream (.tmd)', links.stream || paths.stream, `treemorph-${job.id}.tmd`));
    items.push(link('Metrics (.json)', links.metrics || paths.metrics, `treemorph-${job.id}-metrics.json`));
  }
  // A failed or cancelled job's outputs are gone; a running one's published frames can be fetched.
  if (((job.frames_ready ?? 0) > 0 && job.status === 'running') || job.status === 'succeeded') {
    const a = h('a', { href: '#', download: '' }, 'Current frame (.glb)');
    a.addEventListener('click', (e) => {
      // Between frames, the instant under the cursor (rendered on request).
      const t = timeline.instant;
      const i = Math.max(0, Math.floor(Number($('scrub').value) || 0));
      const path = t !== null && job.status === 'succeeded' ? `${paths.frameAt}?t=${t}` : paths.frame(i);
      a.href = api.url(path);
      a.download = t !== null ? `treemorph-${job.id}-t-${t.toFixed(4)}.glb` : `treemorph-${job.id}-frame-${i}.glb`;
      download(e, path, a.download);
    });
    items.push(h('li', {}, a));
  }
  $('downloads').replaceChildren(...items);
}

async function download(event, path, filename) {
  if (!storedKey()) return; // the plain link works
  event.preventDefault();
  try {
    const blob = await api.blob(path);
    const url = URL.createObjectURL(blob);
    const a = h('a', { href: url, download: filename });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60_000);
  } catch (e) {
    report(e, `downloading ${filename}`);
  }
}

async function startJob(request) {
  const buttons = [$('morph-run'), $('sketch-run')];
  buttons.forEach((b) => (b.disabled = true));
  status(`Starting a ${request.kind} job…`);
  const thisRun = new JobRun(api, {
    onJob: (job) => {
      if (run === thisRun) renderJob(job);
    },
    onPlayer: () => {
      if (run === thisRun && showing === 'player') timeline.attach(null);
    },
    onStreamEvent: (type, player) => {
      if (run !== thisRun) return;
      if (type === 'header') {
        // Follow the new animation unless the user is busy drawing.
        if (!pad.active) showPlayer(player);
        else $('show-result').hidden = false;
      } else if (showing === 'player' && timeline.player === player) {
        timeline.refresh();
      }
    },
    onError: (e, context) => report(e, `${request.kind} job: ${context}`),
    onEnd: (job) => {
      if (run !== thisRun) return;
      if (job.status === 'succeeded') offerInstants();
      if (job.status === 'failed') report(job.error ? new ApiError(0, job.error.code, job.error.message) : new Error('the job failed'), `${job.kind} job ${job.id}`);
      status(`The ${job.kind} job ${job.status}.`);
    },
  });
  const previous = run;
  run = thisRun;
  try {
    await thisRun.start(request);
    // Follow one job at a time; the previous one goes on on the server.
    if (previous && !previous.finished) previous.detach();
    renderJob(thisRun.job);
    status(`${request.kind} job started.`);
  } catch (e) {
    run = previous;
    report(e, `starting a ${request.kind} job`);
    status('');
  } finally {
    buttons.forEach((b) => (b.disabled = false));
    fillTreeSelects(trees.trees);
  }
}

$('job-cancel').addEventListener('click', async () => {
  if (!run) return;
  try {
    await run.cancel();
    status('Cancellation requested.');
  } catch (e) {
    report(e, 'cancelling the job');
  }
});
$('show-result').addEventListener('click', () => {
  if (run && run.player) showPlayer(run.player, { frame: false });
});

// ---- start ----

renderStages(null, null);
await trees.load();
if (trees.trees.length) viewTree(trees.trees[0]);

/** For debugging from the console (and read by the browser test's diagnostics). */
window.treemorph = {
  viewer,
  timeline,
  pad,
  get run() {
    return run;
  },
};
