/**
 * @file The 3D view: a three.js renderer on one canvas with an orbit
 * camera, daylight lighting and a ground disc, showing one thing at a time
 * (a tree's GLB or a stream player's meshes).
 *
 * Why render on demand: the page often sits idle over a static tree, and
 * CI runs it in software GL (SwiftShader) on two cores. The loop runs
 * every animation frame but only draws when something changed — the
 * camera moved, the content changed, a tick callback (the player) asked
 * for it, or the canvas was resized.
 *
 * Framing: the first content is framed from a three-quarter view; later
 * content keeps the direction the user orbited to and only refits the
 * distance, so switching between a tree and its animation does not jump.
 */

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

/** The camera's vertical field of view (degrees). */
export const FOV_DEG = 40;
/** Background colour: a pale sky, distinct from every tree material (the browser test relies on it). */
export const BACKGROUND = 0xdde7ee;

export class Viewer {
  /** @param {HTMLCanvasElement} canvas */
  constructor(canvas) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
    this.renderer.setPixelRatio(Math.min(globalThis.devicePixelRatio || 1, 2));
    this.renderer.outputColorSpace = THREE.SRGBColorSpace;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    this.camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 0.01, 1000);
    this.camera.position.set(4, 3, 8);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = true;
    this.controls.dampingFactor = 0.12;
    this.controls.target.set(0, 2, 0);
    // Keep the camera above the ground: looking up from below a tree is never useful.
    this.controls.maxPolarAngle = Math.PI * 0.52;
    this.controls.addEventListener('change', () => this.changed());
    // Arrow keys pan while the canvas has focus (it is in the tab order).
    this.controls.listenToKeyEvents(canvas);

    const hemi = new THREE.HemisphereLight(0xeaf4ff, 0x6b5a3e, 1.7);
    const sun = new THREE.DirectionalLight(0xfff4e0, 2.1);
    sun.position.set(5, 10, 6);
    const fill = new THREE.DirectionalLight(0xdde8ff, 0.5);
    fill.position.set(-6, 3, -4);
    this.scene.add(hemi, sun, fill);

    this.ground = new THREE.Mesh(
      new THREE.CircleGeometry(1, 96).rotateX(-Math.PI / 2),
      new THREE.MeshStandardMaterial({ color: 0xb8b09a, roughness: 1, metalness: 0 }),
    );
    this.ground.name = 'ground';
    this.ground.visible = false; // until there is something to stand on it
    this.scene.add(this.ground);

    /** @type {THREE.Object3D|null} */
    this.content = null;
    this.framedOnce = false;
    this.dirty = true;
    /** @type {Set<(dt: number) => boolean|void>} */
    this.tickers = new Set();
    /** @type {Set<() => void>} */
    this.viewListeners = new Set();
    this.lastTime = performance.now();

    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    this.renderer.setAnimationLoop((time) => this.loop(time));
  }

  /** Asks for a redraw and tells view listeners (the sketch overlay) that the camera may have moved. */
  changed() {
    this.dirty = true;
    for (const f of this.viewListeners) f();
  }

  resize() {
    const w = Math.max(1, this.canvas.clientWidth);
    const h = Math.max(1, this.canvas.clientHeight);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.changed();
  }

  loop(time) {
    const dt = Math.min(0.25, (time - this.lastTime) / 1000);
    this.lastTime = time;
    for (const tick of this.tickers) if (tick(dt)) this.dirty = true;
    this.controls.update(); // damping; emits 'change' while moving
    if (!this.dirty) return;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
  }

  /**
   * Registers a callback run every animation frame with the elapsed
   * seconds; returning true requests a redraw. Returns an unregister function.
   */
  onTick(tick) {
    this.tickers.add(tick);
    return () => this.tickers.delete(tick);
  }

  /** Calls `f` whenever the camera or canvas changes. */
  onViewChange(f) {
    this.viewListeners.add(f);
  }

  /**
   * Shows `object` instead of the current content (which is removed, not
   * disposed: the owner decides). Frames the camera on `box` (the object's
   * bounds by default).
   * @param {THREE.Object3D|null} object
   * @param {{box?: THREE.Box3, frame?: boolean}} [options]
   */
  setContent(object, { box, frame = true } = {}) {
    if (this.content) this.scene.remove(this.content);
    this.content = object;
    if (object) {
      this.scene.add(object);
      const bounds = box || new THREE.Box3().setFromObject(object);
      if (!bounds.isEmpty()) {
        this.fitGround(bounds);
        if (frame) this.frame(bounds);
      }
    }
    this.changed();
  }

  /** Sizes and places the ground disc under `box`. */
  fitGround(box) {
    const size = box.getSize(new THREE.Vector3());
    const center = box.getCenter(new THREE.Vector3());
    const radius = Math.max(0.6 * Math.hypot(size.x, size.z), 0.45 * size.y, 0.5);
    this.ground.scale.setScalar(radius);
    this.ground.visible = true;
    // Slightly below the lowest point so the trunk base does not z-fight with the disc.
    this.ground.position.set(center.x, Math.min(box.min.y, 0) - 0.002 * Math.max(size.y, 1), center.z);
  }

  /** Points the camera at `box` so all of it is visible. */
  frame(box) {
    const sphere = box.getBoundingSphere(new THREE.Sphere());
    const r = Math.max(sphere.radius, 0.05);
    const vFov = THREE.MathUtils.degToRad(this.camera.fov);
    const hFov = 2 * Math.atan(Math.tan(vFov / 2) * this.camera.aspect);
    const distance = (r / Math.sin(Math.min(vFov, hFov) / 2)) * 1.08;
    let dir;
    if (this.framedOnce) {
      dir = this.camera.position.clone().sub(this.controls.target).normalize();
    } else {
      dir = new THREE.Vector3(0.55, 0.18, 1).normalize();
      this.framedOnce = true;
    }
    this.controls.target.copy(sphere.center);
    this.camera.position.copy(sphere.center).addScaledVector(dir, distance);
    this.camera.near = distance / 200;
    this.camera.far = distance * 20;
    this.camera.updateProjectionMatrix();
    this.controls.maxDistance = distance * 6;
    this.controls.minDistance = r * 0.05;
    this.controls.update();
    this.changed();
  }

  /**
   * The camera as rendered: eye, target and up (metres) and the vertical
   * field of view (degrees), for the sketch pad.
   */
  currentView() {
    return {
      view: {
        eye: this.camera.position.toArray(),
        target: this.controls.target.toArray(),
        up: this.camera.up.toArray(),
      },
      fovDeg: this.camera.fov,
    };
  }

  /** Puts the camera back at `view` (eye, target, up). */
  setView(view) {
    this.camera.up.fromArray(view.up);
    this.camera.position.fromArray(view.eye);
    this.controls.target.fromArray(view.target);
    this.controls.update();
    this.changed();
  }

  /** Whether the camera is (within a millimetre) at `view`. */
  isAt(view) {
    const close = (a, b) => a.every((v, i) => Math.abs(v - b[i]) < 1e-3);
    return (
      close(this.camera.position.toArray(), view.eye) &&
      close(this.controls.target.toArray(), view.target) &&
      close(this.camera.up.toArray(), view.up)
    );
  }

  /** Enables or disables orbiting (off while sketching, so drags draw instead). */
  setOrbitEnabled(enabled) {
    this.controls.enabled = enabled;
    // Damping would keep the camera gliding after the last drag, moving it
    // away from the view a sketch captures; without damping, update() drops
    // the remaining motion at once.
    this.controls.enableDamping = enabled;
    this.controls.update();
    this.changed();
  }

  /**
   * Parses GLB bytes into a scene graph.
   * @param {ArrayBuffer} bytes
   * @returns {Promise<THREE.Group>}
   */
  async parseGlb(bytes) {
    const gltf = await new GLTFLoader().parseAsync(bytes, '');
    return gltf.scene;
  }
}

/** Frees the GPU resources of a GLB scene graph. */
export function disposeObject(object) {
  object.traverse((o) => {
    if (o.geometry) o.geometry.dispose();
    const materials = Array.isArray(o.material) ? o.material : o.material ? [o.material] : [];
    for (const m of materials) {
      for (const value of Object.values(m)) if (value && value.isTexture) value.dispose();
      m.dispose();
    }
  });
}
