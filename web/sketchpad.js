/**
 * @file The sketch pad: a canvas laid over the 3D view on which the user
 * draws a crown silhouette, and the conversion of what was drawn into the
 * normalised device coordinates (NDC) a sketch job expects.
 *
 * ## Why a *square* sketch frame
 * The API's `view` has no aspect ratio: sketch points are NDC "as seen in a
 * square viewport" — x, y ∈ [-1, 1], y up, and `fov_deg` is that square's
 * (vertical = horizontal) field of view. Our canvas is rarely square, so
 * the pad shows the largest centred square of the canvas as the *sketch
 * frame* (the rest is dimmed) and maps that square to [-1, 1]²:
 *
 *   side s = min(w, h),  x = (px − w/2)/(s/2),  y = (h/2 − py)/(s/2),
 *   tan(fov_sq/2) = tan(fov/2) · s/h
 *
 * where `fov` is the vertical field of view the camera renders with. On a
 * landscape canvas s = h, so `fov_sq = fov`; on a portrait one the square
 * is narrower than the canvas and so is its field of view. This is exact,
 * not an approximation: a pixel's ray through the rendered camera and the
 * ray through the square camera at the sent NDC are the same ray
 * (web/test/sketchpad.test.js checks it against the server's projection).
 * Points dragged outside the frame are clamped to its edge.
 *
 * ## Why the sketch remembers its view
 * A sketch only means something together with the camera it was drawn
 * from. The first point captures the camera (eye, target, up, square fov);
 * that view is what the job is sent with, whatever the camera does later.
 * Orbiting is disabled while the pad is active, and activating the pad on
 * an existing sketch puts the camera back where the sketch was drawn.
 * Points are stored in NDC of that view, so resizing the window redraws
 * them where they belong.
 */

/** Smallest move, in CSS pixels, that adds a point while dragging. */
export const MIN_POINT_SPACING_PX = 3;
/** The sketch pipeline's limit on points (crates/sketch `Sketch::MAX_POINTS`). */
export const MAX_POINTS = 10_000;

const DEG = Math.PI / 180;

/**
 * Field of view (degrees) of the centred square of a `width`×`height`
 * viewport rendered with vertical field of view `fovDeg`.
 */
export function squareFovDeg(fovDeg, width, height) {
  if (width >= height) return fovDeg; // exactly, not through tan/atan round-off
  const s = Math.min(width, height);
  return (2 * Math.atan((Math.tan((fovDeg * DEG) / 2) * s) / height)) / DEG;
}

/**
 * Maps between canvas pixels (CSS px, origin top-left, y down) and the
 * square NDC of a sketch view, for a canvas rendered with vertical field of
 * view `fovDeg`. `sketchFovDeg` is the sketch view's square fov (by default
 * the one of this canvas): after a resize the mapping still lands the
 * points on the same rays.
 */
export class ScreenMapping {
  /**
   * @param {number} width Canvas width (CSS px).
   * @param {number} height Canvas height (CSS px).
   * @param {number} fovDeg Vertical fov the camera renders with (degrees).
   * @param {number} [sketchFovDeg] The sketch view's square fov (degrees).
   */
  constructor(width, height, fovDeg, sketchFovDeg = squareFovDeg(fovDeg, width, height)) {
    this.width = width;
    this.height = height;
    this.fovDeg = fovDeg;
    this.sketchFovDeg = sketchFovDeg;
    // Pixels per NDC unit: (h/2) · tan(fov_sq/2) / tan(fov/2).
    this.scale = ((height / 2) * Math.tan((sketchFovDeg * DEG) / 2)) / Math.tan((fovDeg * DEG) / 2);
  }

  /** NDC of a pixel (not clamped). @returns {[number, number]} */
  toNdc(px, py) {
    return [(px - this.width / 2) / this.scale, (this.height / 2 - py) / this.scale];
  }

  /** Pixel of an NDC point. @returns {[number, number]} */
  toPixel(x, y) {
    return [this.width / 2 + x * this.scale, this.height / 2 - y * this.scale];
  }

  /** The sketch frame (NDC [-1, 1]²) in pixels: `{x, y, size}` of its top-left corner and side. */
  frame() {
    return { x: this.width / 2 - this.scale, y: this.height / 2 - this.scale, size: 2 * this.scale };
  }
}

/** Clamps an NDC point into the sketch frame. @returns {[number, number]} */
export function clampNdc([x, y]) {
  return [Math.max(-1, Math.min(1, x)), Math.max(-1, Math.min(1, y))];
}

/**
 * A sketch: one polyline (NDC points) built from strokes, open or closed,
 * with the view it was drawn from. A stroke is one drag (or one click,
 * which adds a single vertex, so outlines can also be drawn point by point);
 * consecutive strokes continue the same polyline, and undo removes the
 * last stroke.
 */
export class Sketch {
  constructor() {
    /** @type {[number, number][]} */
    this.points = [];
    /** Index in `points` where each stroke starts. @type {number[]} */
    this.strokeStarts = [];
    this.closed = true;
    /** The camera the sketch was drawn from (set with the first point). @type {object|null} */
    this.view = null;
    this.drawing = false;
  }

  /** Whether there is nothing to undo. */
  get empty() {
    return this.points.length === 0;
  }

  /**
   * Starts a stroke at `ndc` (clamped to the frame). `view` is captured when
   * this is the sketch's first point.
   */
  begin(ndc, view) {
    if (this.points.length >= MAX_POINTS) return false;
    if (this.empty) this.view = view;
    this.strokeStarts.push(this.points.length);
    this.points.push(clampNdc(ndc));
    this.drawing = true;
    return true;
  }

  /**
   * Continues the stroke; the point is kept only if it is at least
   * `minSpacing` (NDC units) from the last one, so a slow drag does not
   * pile up points. Returns whether it was kept.
   */
  extend(ndc, minSpacing = 0) {
    if (!this.drawing || this.points.length >= MAX_POINTS) return false;
    const p = clampNdc(ndc);
    const last = this.points[this.points.length - 1];
    if (Math.hypot(p[0] - last[0], p[1] - last[1]) < minSpacing) return false;
    this.points.push(p);
    return true;
  }

  /** Ends the stroke. */
  end() {
    this.drawing = false;
  }

  /** Removes the last stroke. */
  undo() {
    if (this.strokeStarts.length === 0) return;
    this.points.length = this.strokeStarts.pop();
    this.drawing = false;
    if (this.empty) this.view = null;
  }

  /** Removes everything (including the captured view). */
  clear() {
    this.points = [];
    this.strokeStarts = [];
    this.view = null;
    this.drawing = false;
  }

  /**
   * Why the sketch cannot be sent yet, or null when it can: a closed
   * outline needs 3 distinct points, an open stroke 2.
   */
  problem() {
    const distinct = new Set(this.points.map(([x, y]) => `${x.toFixed(4)},${y.toFixed(4)}`)).size;
    const need = this.closed ? 3 : 2;
    if (distinct < need) {
      return this.closed
        ? 'draw a closed outline (at least 3 points) around the crown first'
        : 'draw a stroke (at least 2 points) first';
    }
    return null;
  }

  /** The `sketch` member of a sketch job request. */
  toRequest() {
    return {
      points: this.points.map(([x, y]) => [round6(x), round6(y)]),
      closed: this.closed,
    };
  }
}

/** Rounds to 6 decimals: NDC precision far below a pixel, and shorter JSON. */
function round6(v) {
  return Math.round(v * 1e6) / 1e6;
}

/**
 * The overlay: draws the sketch frame and the polyline, and turns pointer
 * drags into strokes. It does not know three.js: the viewer hands it the
 * current view and field of view through callbacks.
 */
export class SketchPad {
  /**
   * @param {HTMLCanvasElement} canvas The overlay canvas (same box as the 3D canvas).
   * @param {object} hooks
   * @param {() => {view: object, fovDeg: number}} hooks.currentView The camera as rendered now:
   *   `view` without `fov_deg` (eye, target, up) and the camera's vertical fov.
   * @param {(view: object) => boolean} [hooks.isAt] Whether the camera is at `view` now: an
   *   inactive pad shows the sketch only then (elsewhere it would outline the wrong thing).
   * @param {() => void} [hooks.onChange] Called when the sketch changes.
   */
  constructor(canvas, { currentView, isAt = () => true, onChange = () => {} }) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.currentView = currentView;
    this.isAt = isAt;
    this.onChange = onChange;
    this.sketch = new Sketch();
    this.active = false;
    this.pointerId = null;
    this.fovDeg = 45;
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    canvas.addEventListener('pointermove', (e) => this.move(e));
    canvas.addEventListener('pointerup', (e) => this.up(e));
    canvas.addEventListener('pointercancel', (e) => this.up(e));
    new ResizeObserver(() => this.redraw()).observe(canvas);
  }

  /** Turns drawing on or off (off: pointer events go to the 3D view). */
  setActive(active) {
    this.active = active;
    this.canvas.classList.toggle('active', active);
    this.redraw();
  }

  /** The mapping for the canvas as it is now. */
  mapping() {
    const { fovDeg } = this.currentView();
    this.fovDeg = fovDeg;
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    const sketchFov = this.sketch.view ? this.sketch.view.fov_deg : undefined;
    return new ScreenMapping(w, h, fovDeg, sketchFov);
  }

  eventPixel(e) {
    const r = this.canvas.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }

  down(e) {
    if (!this.active || e.button !== 0 || this.pointerId !== null) return;
    e.preventDefault();
    const { view, fovDeg } = this.currentView();
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    const captured = { ...view, fov_deg: squareFovDeg(fovDeg, w, h) };
    const m = this.sketch.view ? this.mapping() : new ScreenMapping(w, h, fovDeg);
    const [px, py] = this.eventPixel(e);
    if (!this.sketch.begin(m.toNdc(px, py), captured)) return;
    this.pointerId = e.pointerId;
    this.canvas.setPointerCapture(e.pointerId);
    this.redraw();
    this.onChange();
  }

  move(e) {
    if (e.pointerId !== this.pointerId) return;
    const m = this.mapping();
    // Coalesced events keep fast strokes smooth where the browser batches moves.
    const events = typeof e.getCoalescedEvents === 'function' ? e.getCoalescedEvents() : [];
    let added = false;
    for (const ev of events.length ? events : [e]) {
      const [px, py] = this.eventPixel(ev);
      added = this.sketch.extend(m.toNdc(px, py), MIN_POINT_SPACING_PX / m.scale) || added;
    }
    if (added) this.redraw();
  }

  up(e) {
    if (e.pointerId !== this.pointerId) return;
    this.pointerId = null;
    this.sketch.end();
    this.redraw();
    this.onChange();
  }

  /** Undoes the last stroke. */
  undo() {
    this.sketch.undo();
    this.redraw();
    this.onChange();
  }

  /** Clears the sketch. */
  clear() {
    this.sketch.clear();
    this.redraw();
    this.onChange();
  }

  /** Sets whether the outline is closed. */
  setClosed(closed) {
    this.sketch.closed = closed;
    this.redraw();
    this.onChange();
  }

  /** Redraws the overlay (after a change, a resize or a camera move). */
  redraw() {
    const dpr = globalThis.devicePixelRatio || 1;
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    if (this.canvas.width !== Math.round(w * dpr) || this.canvas.height !== Math.round(h * dpr)) {
      this.canvas.width = Math.round(w * dpr);
      this.canvas.height = Math.round(h * dpr);
    }
    const ctx = this.ctx;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    if (this.sketch.empty && !this.active) return;
    if (!this.active && this.sketch.view && !this.isAt(this.sketch.view)) return;
    const m = this.mapping();
    if (this.active) {
      // Dim what lies outside the sketch frame and outline the frame.
      const f = m.frame();
      ctx.fillStyle = 'rgba(20, 30, 40, 0.28)';
      ctx.beginPath();
      ctx.rect(0, 0, w, h);
      ctx.rect(f.x, f.y, f.size, f.size);
      ctx.fill('evenodd');
      ctx.strokeStyle = 'rgba(255, 255, 255, 0.8)';
      ctx.setLineDash([6, 6]);
      ctx.lineWidth = 1;
      ctx.strokeRect(f.x + 0.5, f.y + 0.5, f.size - 1, f.size - 1);
      ctx.setLineDash([]);
    }
    const pts = this.sketch.points.map(([x, y]) => m.toPixel(x, y));
    if (pts.length === 0) return;
    ctx.lineJoin = 'round';
    ctx.lineCap = 'round';
    const path = () => {
      ctx.beginPath();
      ctx.moveTo(pts[0][0], pts[0][1]);
      for (const [x, y] of pts.slice(1)) ctx.lineTo(x, y);
    };
    // A dark halo under a bright line reads on both sky and foliage.
    path();
    ctx.strokeStyle = 'rgba(0, 0, 0, 0.55)';
    ctx.lineWidth = 5;
    ctx.stroke();
    path();
    ctx.strokeStyle = '#ffd54a';
    ctx.lineWidth = 2.5;
    ctx.stroke();
    if (this.sketch.closed && pts.length > 2) {
      const [a, b] = [pts[pts.length - 1], pts[0]];
      ctx.setLineDash([5, 5]);
      ctx.beginPath();
      ctx.moveTo(a[0], a[1]);
      ctx.lineTo(b[0], b[1]);
      ctx.strokeStyle = '#ffd54a';
      ctx.lineWidth = 2;
      ctx.stroke();
      ctx.setLineDash([]);
    }
    // Mark where strokes start, so undo's unit is visible.
    ctx.fillStyle = '#ffd54a';
    for (const i of this.sketch.strokeStarts) {
      const [x, y] = pts[i];
      ctx.beginPath();
      ctx.arc(x, y, 3.5, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
}
