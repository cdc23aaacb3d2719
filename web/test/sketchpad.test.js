// The sketch pad's geometry and polyline logic: canvas pixels → the square
// NDC a sketch job expects (checked against the server's own projection,
// re-implemented from crates/sketch/src/view.rs), and the stroke model.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as THREE from 'three';

import { MAX_POINTS, ScreenMapping, Sketch, clampNdc, squareFovDeg } from '../sketchpad.js';

/** The server's projection (crates/sketch `Camera::project`, aspect 1). */
function serverProject(view, p) {
  const v = (a) => new THREE.Vector3(...a);
  const eye = v(view.eye);
  const forward = v(view.target).sub(eye).normalize();
  const right = forward.clone().cross(v(view.up)).normalize();
  const up = right.clone().cross(forward).normalize();
  const d = v(p).sub(eye);
  const depth = d.dot(forward);
  const half = Math.tan((view.fov_deg * Math.PI) / 360) * depth;
  return [d.dot(right) / half, d.dot(up) / half];
}

/** Where three.js draws `p` on a w×h canvas (CSS px) with this camera. */
function threePixel(camera, w, h, p) {
  const ndc = new THREE.Vector3(...p).project(camera);
  return [((ndc.x + 1) / 2) * w, ((1 - ndc.y) / 2) * h];
}

const cases = [
  { w: 1280, h: 800, fov: 40 }, // landscape
  { w: 390, h: 844, fov: 40 }, // portrait phone
  { w: 600, h: 600, fov: 55 }, // square
];

test('a drawn pixel lands on the same ray for the server, on landscape, portrait and square canvases', () => {
  const points = [[0.3, 2.1, -0.4], [-1.2, 0.4, 0.9], [0.8, 3.3, 1.5], [0, 1.5, 0]];
  for (const { w, h, fov } of cases) {
    const camera = new THREE.PerspectiveCamera(fov, w / h, 0.1, 100);
    camera.position.set(4, 2.5, 6);
    camera.up.set(0, 1, 0);
    const target = [0.2, 1.6, -0.1];
    camera.lookAt(...target);
    camera.updateMatrixWorld();
    const view = { eye: camera.position.toArray(), target, up: [0, 1, 0], fov_deg: squareFovDeg(fov, w, h) };
    const mapping = new ScreenMapping(w, h, fov);
    for (const p of points) {
      const [px, py] = threePixel(camera, w, h, p);
      const [x, y] = mapping.toNdc(px, py);
      const [sx, sy] = serverProject(view, p);
      assert.ok(Math.abs(x - sx) < 1e-9 && Math.abs(y - sy) < 1e-9, `${w}x${h} ${p}: ${[x, y]} vs ${[sx, sy]}`);
      const back = mapping.toPixel(x, y);
      assert.ok(Math.abs(back[0] - px) < 1e-9 && Math.abs(back[1] - py) < 1e-9);
    }
  }
});

test('the sketch frame is the centred square of the canvas and maps to [-1, 1]²', () => {
  for (const { w, h, fov } of cases) {
    const m = new ScreenMapping(w, h, fov);
    const s = Math.min(w, h);
    const f = m.frame();
    assert.ok(Math.abs(f.size - s) < 1e-9 && Math.abs(f.x - (w - s) / 2) < 1e-9 && Math.abs(f.y - (h - s) / 2) < 1e-9);
    assert.deepEqual(m.toNdc(w / 2, h / 2), [0, 0]);
    const [x0, y0] = m.toNdc(f.x, f.y);
    assert.ok(Math.abs(x0 + 1) < 1e-12 && Math.abs(y0 - 1) < 1e-12, 'top-left corner is (-1, 1): y up');
  }
  // Landscape keeps the camera's fov; portrait narrows it.
  assert.equal(squareFovDeg(40, 1280, 800), 40);
  assert.ok(squareFovDeg(40, 390, 844) < 40);
});

test('a sketch keeps its own fov after a resize: points stay on their rays', () => {
  // Drawn on a portrait canvas, then the window becomes landscape.
  const fov = 40;
  const drawn = new ScreenMapping(400, 800, fov);
  const sketchFov = drawn.sketchFovDeg;
  const ndc = drawn.toNdc(300, 200);
  const resized = new ScreenMapping(1200, 800, fov, sketchFov);
  const [px, py] = resized.toPixel(...ndc);
  // Same ray: the angle from the centre (in units of the vertical half-height) is preserved.
  const slope = (p, c, half) => ((p - c) / half) * Math.tan((fov * Math.PI) / 360);
  assert.ok(Math.abs(slope(300, 200, 400) - slope(px, 600, 400)) < 1e-12);
  assert.ok(Math.abs(slope(200, 400, 400) - slope(py, 400, 400)) < 1e-12);
});

test('strokes build one polyline; undo removes the last stroke; clear resets the view', () => {
  const s = new Sketch();
  const view = { eye: [0, 1, 5], target: [0, 1, 0], up: [0, 1, 0], fov_deg: 40 };
  assert.equal(s.problem() !== null, true);
  s.begin([0, 0.8], view);
  assert.equal(s.extend([0.001, 0.8], 0.01), false, 'too close to the last point');
  assert.equal(s.extend([0.5, 0], 0.01), true);
  s.end();
  assert.equal(s.extend([0.9, 0.9], 0), false, 'not drawing');
  s.begin([0, -0.8], { ...view, eye: [9, 9, 9] });
  s.extend([-0.5, 0]);
  s.end();
  assert.equal(s.view, view, 'the first point captured the view');
  assert.deepEqual(s.points, [[0, 0.8], [0.5, 0], [0, -0.8], [-0.5, 0]]);
  assert.equal(s.problem(), null);
  assert.deepEqual(s.toRequest(), { points: [[0, 0.8], [0.5, 0], [0, -0.8], [-0.5, 0]], closed: true });
  s.undo();
  assert.deepEqual(s.points, [[0, 0.8], [0.5, 0]]);
  assert.match(s.problem(), /closed outline/);
  s.closed = false;
  assert.equal(s.problem(), null, 'two points make an open stroke');
  s.undo();
  assert.ok(s.empty);
  assert.equal(s.view, null);
  s.undo(); // nothing to undo: no error
  s.begin([2, -3], view);
  assert.deepEqual(s.points, [[1, -1]], 'clamped into the frame');
  s.clear();
  assert.ok(s.empty && s.view === null && s.strokeStarts.length === 0);
});

test('points are clamped, rounded for the request, and capped at the pipeline limit', () => {
  assert.deepEqual(clampNdc([1.5, -0.2]), [1, -0.2]);
  const s = new Sketch();
  s.begin([0.1234567891, -0.5], null);
  assert.deepEqual(s.toRequest().points, [[0.123457, -0.5]]);
  for (let i = 0; i < MAX_POINTS + 10; i++) s.extend([Math.cos(i), Math.sin(i)], 0);
  assert.equal(s.points.length, MAX_POINTS);
  assert.equal(s.begin([0, 0], null), false);
});

test('repeated clicks on one spot do not count as an outline', () => {
  const s = new Sketch();
  for (let i = 0; i < 5; i++) {
    s.begin([0.2, 0.2], null);
    s.end();
  }
  assert.match(s.problem(), /at least 3 points/);
});
